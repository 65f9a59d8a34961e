"""Anti-aliasing by supersampling: the exact s-times camera and a trainer step at s = 2 and 4
that matches a host-side reference of the same chain (the area-downsampling kernel and its
transpose alone: tests/kernels/test_loss.py)."""

import numpy as np
import pytest

from tsplus_wgpu.kernels.loss import supersampled_camera
from tsplus_wgpu.reference.loss import downsample_area, downsample_area_t
from tsplus_wgpu.types import Camera


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
    cam = t.scene.cameras[view]            # the trainer's frame, as its device model
    fine = renderer.forward(t.model, supersampled_camera(cam, 4), t.sched.sigma(11), cfg.background, cfg.near).image
    stats = t.step(read_stats=True)
    assert stats["supersample"] == 4
    h, w = cam.height, cam.width
    v_img = t.ctx.read(renderer.scratch.get("train_v_image", 12 * h * w), np.float32, 3 * h * w).reshape(h, w, 3)
    v_out = t.ctx.read(renderer.scratch.get("train_v_out", 16 * h * w * 16), np.float32, 4 * h * w * 16)
    np.testing.assert_allclose(v_out.reshape(4 * h, 4 * w, 4)[..., :3], downsample_area_t(v_img, 4),
                               atol=1e-9)
    ds = downsample_area(fine, 4)
    from tsplus_wgpu.train.trainer import psnr
    assert abs(stats["psnr"] - psnr(ds, scene.images[view])) < 1e-3
    # evaluation renders at s = 4 (fits easily) and is the block mean of the 4x render
    img = t.render(t.model, t.scene.cameras[0], 0.5, supersample=4)
    big = renderer.forward(t.model, supersampled_camera(t.scene.cameras[0], 4), 0.5, cfg.background, cfg.near).image
    np.testing.assert_allclose(img, downsample_area(big, 4), atol=1e-6)
    assert t.fit_supersample(cam, 4) == 4
    big, mid = Camera(4000, 3000, 1.0, 1.0, 0.0, 0.0, np.eye(4)), Camera(1000, 1000, 1.0, 1.0, 0.0, 0.0, np.eye(4))
    saved = dict(t.ctx.limits)     # the answer depends on the device's sizes: set them (any adapter)
    try:
        t.ctx.limits.update({"max-storage-buffer-binding-size": 2**27, "max-buffer-size": 2**28})   # WebGPU's
        assert t.fit_supersample(big, 4) == 1       # 16 B x 12M x s^2 over 128 MiB even at s = 2
        assert t.fit_supersample(mid, 4) == 2
        t.ctx.limits.update({"max-storage-buffer-binding-size": 2**31 - 256, "max-buffer-size": 2**31 - 256})
        assert t.fit_supersample(big, 4) == 2 and t.fit_supersample(mid, 4) == 4          # an H100's 2 GiB
        t.ctx.limits.update({"max-buffer-size": 2**27})                                   # the smaller of the two
        assert t.fit_supersample(mid, 4) == 2
    finally:
        t.ctx.limits.clear()
        t.ctx.limits.update(saved)
