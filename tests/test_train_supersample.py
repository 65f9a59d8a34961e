"""Anti-aliasing by supersampling: the exact s-times camera, the area-downsampling kernel and
its transpose against float64 twins (forward = block mean, adjoint identity), and a trainer
step at s = 2 and 4 that matches a host-side reference of the same chain."""

import numpy as np
import pytest

from tsplus_wgpu.train.kernels import (DownsampleArea, DownsampleAreaT, downsample_area_reference,
                                       downsample_area_t_reference, supersampled_camera)
from tsplus_wgpu.types import Camera


def _run_down(renderer, fine, s):
    c = renderer.ctx
    sh, sw = fine.shape[:2]
    h, w = sh // s, sw // s
    out = c.buffer(12 * h * w)
    enc = c.device.create_command_encoder()
    DownsampleArea(c)(enc, c.upload(np.ascontiguousarray(fine, np.float32)), out, w, h, s)
    c.queue.submit([enc.finish()])
    return c.read(out, np.float32, 3 * h * w).reshape(h, w, 3)


def _run_down_t(renderer, v, s):
    c = renderer.ctx
    h, w = v.shape[:2]
    out = c.buffer(16 * h * w * s * s)
    enc = c.device.create_command_encoder()
    DownsampleAreaT(c)(enc, c.upload(np.ascontiguousarray(v, np.float32)), out, w, h, s)
    c.queue.submit([enc.finish()])
    return c.read(out, np.float32, 4 * h * w * s * s).reshape(h * s, w * s, 4)


@pytest.mark.parametrize("s,h,w", [(1, 5, 7), (2, 13, 9), (4, 6, 11), (3, 4, 5)])
def test_downsample_is_the_block_mean_and_transpose_is_its_adjoint(renderer, s, h, w):
    rng = np.random.default_rng(s)
    x = rng.uniform(-1, 1, size=(h * s, w * s, 3)).astype(np.float32)
    y = rng.uniform(-1, 1, size=(h, w, 3)).astype(np.float32)
    ax = _run_down(renderer, x, s)
    np.testing.assert_allclose(ax, downsample_area_reference(x, s), rtol=0, atol=1e-6)
    if s == 1:
        np.testing.assert_array_equal(ax, x)
    aty = _run_down_t(renderer, y, s)
    assert np.all(aty[..., 3] == 0)
    np.testing.assert_allclose(aty[..., :3], downsample_area_t_reference(y, s), rtol=0, atol=1e-7)
    # <A x, y> = <x, A^T y>, for the kernels and for the twins
    lhs = float(np.sum(ax.astype(np.float64) * y))
    rhs = float(np.sum(x.astype(np.float64) * aty[..., :3]))
    assert abs(lhs - rhs) <= 1e-5 * max(1.0, abs(lhs))
    xr = x.astype(np.float64)
    assert np.isclose(np.sum(downsample_area_reference(xr, s) * y), np.sum(xr * downsample_area_t_reference(y, s)),
                      rtol=1e-12, atol=1e-12)


def test_supersampled_camera_sub_pixel_centres_average_to_the_pixel():
    cam = Camera(7, 5, 30.0, 31.0, 3.2, 2.7, np.eye(4))
    assert supersampled_camera(cam, 1) is cam
    for s in (2, 4):
        c = supersampled_camera(cam, s)
        assert (c.width, c.height, c.fx, c.fy, c.cx, c.cy) == (7 * s, 5 * s, 30.0 * s, 31.0 * s, 3.2 * s, 2.7 * s)
        # a world point projecting to pixel coordinate u at 1x projects to s u at s x; the
        # sub-pixel centres (J + 0.5) / s of pixel j average to j + 0.5
        j = 3
        centres = [(s * j + b + 0.5) / s for b in range(s)]
        assert np.isclose(np.mean(centres), j + 0.5)
        x = np.array([0.1, -0.05, 2.0])
        u1 = cam.fx * x[0] / x[2] + cam.cx
        us = c.fx * x[0] / x[2] + c.cx
        assert np.isclose(us, s * u1)
    with pytest.raises(ValueError, match="supersampling"):
        supersampled_camera(cam, 0)


def test_trainer_step_supersampled_matches_host_chain(renderer):
    """One training step at s = 4: the logged image is the block mean of the s-times render,
    the gradient that reaches the backward equals the host transpose of the loss gradient."""
    from tsplus_wgpu.data import load_procedural
    from tsplus_wgpu.train.trainer import TrainConfig, Trainer
    scene = load_procedural("tiny")
    cfg = TrainConfig(iterations=12, quick=True, topology=False)
    t = Trainer(scene, cfg, renderer=renderer)
    t.iteration = 10                       # quick 12: s = 2 from 8, s = 4 from 10
    assert t.sched.supersample(11) == 4
    view = t.view_of(11)
    cam = scene.cameras[view]
    fine = renderer.forward(t.model, supersampled_camera(cam, 4), t.sched.sigma(11), cfg.background, cfg.near).image
    stats = t.step(read_stats=True)
    assert stats["supersample"] == 4
    h, w = cam.height, cam.width
    v_img = t.ctx.read(renderer.scratch.get("train_v_image", 12 * h * w), np.float32, 3 * h * w).reshape(h, w, 3)
    v_out = t.ctx.read(renderer.scratch.get("train_v_out", 16 * h * w * 16), np.float32, 4 * h * w * 16)
    np.testing.assert_allclose(v_out.reshape(4 * h, 4 * w, 4)[..., :3], downsample_area_t_reference(v_img, 4),
                               atol=1e-9)
    ds = downsample_area_reference(fine, 4)
    from tsplus_wgpu.train.trainer import psnr
    assert abs(stats["psnr"] - psnr(ds, scene.images[view])) < 1e-3
    # evaluation renders at s = 4 (fits easily) and is the block mean of the 4x render
    img = t.render(t.model, scene.cameras[0], 0.5, supersample=4)
    big = renderer.forward(t.model, supersampled_camera(scene.cameras[0], 4), 0.5, cfg.background, cfg.near).image
    np.testing.assert_allclose(img, downsample_area_reference(big, 4), atol=1e-6)
    assert t.fit_supersample(cam, 4) == 4
    assert t.fit_supersample(Camera(4000, 3000, 1.0, 1.0, 0.0, 0.0, np.eye(4)), 4) == 1   # 16 B x 192M: too big
    assert t.fit_supersample(Camera(1000, 1000, 1.0, 1.0, 0.0, 0.0, np.eye(4)), 4) == 2
