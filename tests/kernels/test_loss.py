"""shaders/loss/: each kernel alone against its float64 twin (tsplus_wgpu.reference.loss).
The whole ImageLoss chain is tested in tests/test_train_loss.py."""

import numpy as np
import pytest

from tsplus_wgpu.kernels.loss import (DownsampleArea, DownsampleAreaT, PackVOut, SsimBlurH, SsimGradH, SsimGradV,
                                      SsimLoss, SsimReduce)
import tsplus_wgpu.reference.loss as twin
from scenes import submit as _run, rel_error as _rel

# (H, W); 23 x 29 and 40 x 70 span several workgroups; the others cut the runs of SSIM_SEG = 16
# pixels along rows and columns anywhere (1, 15, 16, 17, 35 = 2 x 16 + 3)
SIZES = [(1, 1), (5, 7), (23, 29), (40, 70), (1, 35), (35, 1), (15, 17), (17, 16), (16, 15), (3, 300), (300, 2)]


def _images(shape, seed=2):
    rng = np.random.default_rng(seed)
    return rng.random(shape + (3,)).astype(np.float32), rng.random(shape + (3,)).astype(np.float32)


@pytest.mark.parametrize("shape", SIZES)
def test_ssim_blur_h(ctx, shape):
    h, w = shape
    x, y = _images(shape)
    k = SsimBlurH(ctx)
    rows = ctx.buffer(64 * h * w)
    _run(ctx, lambda enc: k(enc, k.params(w, h), ctx.upload(x), ctx.upload(y), rows, w, h))
    got = ctx.read(rows, np.float32, 16 * h * w).reshape(h, w, 4, 4)
    want = twin.ssim_blur_h(x, y)
    assert _rel(got, want) <= 1e-6
    assert np.all(got[..., 3, 3] == 0)
    # each of the five moments on its own (a dropped or swapped term shows here)
    flat_got, flat_want = got.reshape(h, w, 16), want.reshape(h, w, 16)
    for j in range(5):
        assert _rel(flat_got[..., 3 * j:3 * j + 3], flat_want[..., 3 * j:3 * j + 3]) <= 1e-6, j


@pytest.mark.parametrize("shape", SIZES)
def test_ssim_loss(ctx, shape):
    h, w = shape
    x, y = _images(shape)
    rows = twin.ssim_blur_h(x, y).astype(np.float32)
    k = SsimLoss(ctx)
    groups = k.partial_count(w, h)
    dmaps, partials = ctx.buffer(48 * h * w), ctx.buffer(8 * groups)
    _run(ctx, lambda enc: k(enc, k.params(w, h), ctx.upload(x), ctx.upload(y), ctx.upload(rows), dmaps, partials,
                            w, h))
    want_d, want_p = twin.ssim_loss(x, y, rows)
    got_d = ctx.read(dmaps, np.float32, 12 * h * w).reshape(h, w, 3, 4)
    for j, name in enumerate("abc"):
        assert _rel(got_d[:, :, j, :3], want_d[:, :, j, :3]) <= 2e-5, name
    assert np.all(got_d[..., 3] == 0)
    got_p = ctx.read(partials, np.float32, 2 * groups).reshape(groups, 2)
    assert want_p.shape == (groups, 2)
    np.testing.assert_allclose(got_p, want_p, rtol=2e-6)


@pytest.mark.parametrize("shape", SIZES)
def test_ssim_grad_h(ctx, shape):
    h, w = shape
    rng = np.random.default_rng(3)
    dmaps = rng.normal(size=(h, w, 3, 4)).astype(np.float32)
    dmaps[..., 3] = 0.0
    k = SsimGradH(ctx)
    grows = ctx.buffer(48 * h * w)
    _run(ctx, lambda enc: k(enc, k.params(w, h), ctx.upload(dmaps), grows, w, h))
    got = ctx.read(grows, np.float32, 12 * h * w).reshape(h, w, 3, 4)
    want = twin.ssim_grad_h(dmaps)
    for j in range(3):
        assert _rel(got[:, :, j], want[:, :, j]) <= 1e-6, j


@pytest.mark.parametrize("shape", SIZES)
def test_ssim_grad_v(ctx, shape):
    h, w = shape
    x, y = _images(shape)
    rng = np.random.default_rng(4)
    grows = rng.normal(size=(h, w, 3, 4)).astype(np.float32)
    grows[..., 3] = 0.0
    k = SsimGradV(ctx)
    v = ctx.buffer(12 * h * w)
    _run(ctx, lambda enc: k(enc, k.params(w, h), ctx.upload(x), ctx.upload(y), ctx.upload(grows), v, w, h))
    got = ctx.read(v, np.float32, 3 * h * w).reshape(h, w, 3)
    want = twin.ssim_grad_v(x, y, grows)
    assert _rel(got, want) <= 1e-5
    # the SSIM part alone (the L1 part dominates at these sizes)
    sg = twin.L1_WEIGHT * np.sign(x.astype(np.float64) - y) / x.size
    assert _rel(sg - got, sg - want) <= 1e-5


@pytest.mark.parametrize("num_pixels", [1, 256, 257, 70_000, 200_000])
def test_ssim_reduce(ctx, num_pixels):
    k = SsimReduce(ctx)
    groups = k.groups(num_pixels, per=twin.SSIM_GROUP)
    rng = np.random.default_rng(num_pixels)
    partials = np.stack([rng.random(groups) * 3 * twin.SSIM_GROUP * 0.3,
                         rng.random(groups) * 3 * twin.SSIM_GROUP], axis=1).astype(np.float32)
    partials[-1] *= (num_pixels - (groups - 1) * twin.SSIM_GROUP) / twin.SSIM_GROUP   # the last group is partial
    result = ctx.buffer(16)
    _run(ctx, lambda enc: k(enc, k.params(num_pixels, 1), ctx.upload(partials), result))
    got = ctx.read(result, np.float32, 4)
    want = twin.ssim_reduce(partials, num_pixels)
    np.testing.assert_allclose(got[:3], want[:3], rtol=2e-6)
    assert got[3] == 0.0


def test_pack_v_out(ctx):
    v = np.random.default_rng(1).normal(size=(7, 9, 3)).astype(np.float32)
    out = ctx.buffer(16 * 63)
    stage = PackVOut(ctx)
    _run(ctx, lambda enc: stage(enc, ctx.upload(v), out, 63))
    np.testing.assert_array_equal(ctx.read(out, np.float32, 4 * 63).reshape(63, 4), twin.pack_v_out(v))


def _run_down(ctx, fine, s):
    sh, sw = fine.shape[:2]
    h, w = sh // s, sw // s
    out = ctx.buffer(12 * h * w)
    _run(ctx, lambda enc: DownsampleArea(ctx)(enc, ctx.upload(np.ascontiguousarray(fine, np.float32)), out, w, h, s))
    return ctx.read(out, np.float32, 3 * h * w).reshape(h, w, 3)


def _run_down_t(ctx, v, s):
    h, w = v.shape[:2]
    out = ctx.buffer(16 * h * w * s * s)
    _run(ctx, lambda enc: DownsampleAreaT(ctx)(enc, ctx.upload(np.ascontiguousarray(v, np.float32)), out, w, h, s))
    return ctx.read(out, np.float32, 4 * h * w * s * s).reshape(h * s, w * s, 4)


DOWN_CASES = [(1, 5, 7), (2, 13, 9), (4, 6, 11), (3, 4, 5)]


def _down_data(s, h, w):
    rng = np.random.default_rng(s)
    x = rng.uniform(-1, 1, size=(h * s, w * s, 3)).astype(np.float32)
    y = rng.uniform(-1, 1, size=(h, w, 3)).astype(np.float32)
    return x, y


@pytest.mark.parametrize("s,h,w", DOWN_CASES)
def test_downsample_area(ctx, s, h, w):
    x, y = _down_data(s, h, w)
    ax = _run_down(ctx, x, s)
    np.testing.assert_allclose(ax, twin.downsample_area(x, s), rtol=0, atol=1e-6)
    if s == 1:
        np.testing.assert_array_equal(ax, x)
    # the twins are each other's transpose: <A x, y> = <x, A^T y>
    xr = x.astype(np.float64)
    assert np.isclose(np.sum(twin.downsample_area(xr, s) * y), np.sum(xr * twin.downsample_area_t(y, s)),
                      rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("s,h,w", DOWN_CASES)
def test_downsample_area_t(ctx, s, h, w):
    x, y = _down_data(s, h, w)
    aty = _run_down_t(ctx, y, s)
    assert np.all(aty[..., 3] == 0)
    np.testing.assert_allclose(aty[..., :3], twin.downsample_area_t(y, s), rtol=0, atol=1e-7)


@pytest.mark.parametrize("s,h,w", DOWN_CASES)
def test_downsample_area_kernels_are_adjoint(ctx, s, h, w):
    x, y = _down_data(s, h, w)
    ax, aty = _run_down(ctx, x, s), _run_down_t(ctx, y, s)
    lhs = float(np.sum(ax.astype(np.float64) * y))
    rhs = float(np.sum(x.astype(np.float64) * aty[..., :3]))
    assert abs(lhs - rhs) <= 1e-5 * max(1.0, abs(lhs))
