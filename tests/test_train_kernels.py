"""The trainer's small kernels (train_activate, train_grads, pack_v_out, opacity_reg) against
their float64 twins, and the device-resident forward/backward against the host path."""

import numpy as np
import pytest

from tsplus_wgpu.stages import Scratch
from tsplus_wgpu.train import kernels as K


def _run(ctx, record):
    enc = ctx.device.create_command_encoder()
    record(enc)
    ctx.queue.submit([enc.finish()])


@pytest.mark.parametrize("n,k", [(1, 1), (300, 4), (777, 16)])
@pytest.mark.parametrize("reinvert", [False, True])
def test_activate_matches_twin(ctx, n, k, reinvert):
    rng = np.random.default_rng(n + k)
    sp = rng.normal(size=(k, n, 3)).astype(np.float32)
    w = rng.normal(scale=3.0, size=n).astype(np.float32)
    w[:3] = [-30.0, 0.0, 30.0][: min(3, n)]
    floor, floor_old = (0.35, 0.1) if reinvert else (0.2, None)
    bsp, bw = ctx.upload(sp), ctx.upload(w)
    bsh, bo = ctx.buffer(12 * n * k), ctx.buffer(4 * n)
    stage = K.TrainActivate(ctx)
    _run(ctx, lambda enc: stage(enc, bsp, bw, bsh, bo, n, k, floor, floor_old))
    sh_ref, o_ref, w_ref = K.activate_reference(sp, w, floor, floor_old)
    np.testing.assert_array_equal(ctx.read(bsh, np.float32, 3 * n * k).reshape(n, k, 3), sh_ref.astype(np.float32))
    np.testing.assert_allclose(ctx.read(bo, np.float32, n), o_ref, rtol=0, atol=2e-6)
    w_dev = ctx.read(bw, np.float32, n)
    if reinvert:
        # the logit is ill-conditioned where q is near 0 or 1: compare opacities there
        o_dev = floor + (1 - floor) * K.sigmoid(w_dev)
        np.testing.assert_allclose(o_dev, o_ref, atol=3e-6)
        mid = np.abs(w_ref) < 5
        np.testing.assert_allclose(w_dev[mid], w_ref[mid], atol=2e-4)
    else:
        np.testing.assert_array_equal(w_dev, w)


@pytest.mark.parametrize("n,k,active", [(5, 1, 1), (300, 16, 4), (513, 9, 9)])
@pytest.mark.parametrize("use_reg", [False, True])
def test_grads_match_twin(ctx, n, k, active, use_reg):
    rng = np.random.default_rng(7 * n + k)
    w = rng.normal(scale=2.0, size=n).astype(np.float32)
    vsh = rng.normal(size=(n, k, 3)).astype(np.float32)
    vo = rng.normal(size=n).astype(np.float32)
    reg = np.zeros((n, 4), np.float32)
    reg[:, 0] = rng.normal(size=n)
    floor = 0.3
    bvsp, bvw = ctx.buffer(12 * n * k), ctx.buffer(4 * n)
    stage = K.TrainGrads(ctx)
    _run(ctx, lambda enc: stage(enc, ctx.upload(w), ctx.upload(vsh), ctx.upload(vo), ctx.upload(reg), bvsp, bvw,
                                n, k, active, floor, use_reg))
    vsp_ref, vw_ref = K.grads_reference(w, vsh, vo, floor, active, reg[:, 0] if use_reg else None)
    vsp = ctx.read(bvsp, np.float32, 3 * n * k).reshape(k, n, 3)
    np.testing.assert_array_equal(vsp, vsp_ref.astype(np.float32))
    assert not np.any(vsp[active:])
    np.testing.assert_allclose(ctx.read(bvw, np.float32, n), vw_ref, rtol=1e-5, atol=1e-7)


def test_pack_v_out(ctx):
    v = np.random.default_rng(1).normal(size=(7, 9, 3)).astype(np.float32)
    out = ctx.buffer(16 * 63)
    stage = K.PackVOut(ctx)
    _run(ctx, lambda enc: stage(enc, ctx.upload(v), out, 63))
    np.testing.assert_array_equal(ctx.read(out, np.float32, 4 * 63).reshape(63, 4), K.pack_v_out_reference(v))


@pytest.mark.parametrize("m", [1, 50, 5000])
def test_opacity_reg_matches_twin(ctx, m):
    rng = np.random.default_rng(m)
    n = max(3, m // 3)
    tri = np.stack([rng.choice(n, 3, replace=False) for _ in range(m)]).astype(np.int64)
    op = rng.choice([0.2, 0.5, 0.9], size=n).astype(np.float32)   # many ties
    reg = K.OpacityReg(ctx, Scratch(ctx))
    reg.set_topology(tri)
    vals, out = ctx.buffer(16 * 3 * m), ctx.buffer(16 * n)
    btri = ctx.upload(tri.astype(np.uint32))
    _run(ctx, lambda enc: reg.record(enc, btri, ctx.upload(op), vals, out, 1.9e-6))
    got = ctx.read(out, np.float32, 4 * n).reshape(n, 4)
    want = K.opacity_reg_reference(tri, op, 1.9e-6, n)
    np.testing.assert_allclose(got[:, 0], want, rtol=1e-5, atol=1e-15)
    assert not np.any(got[:, 1:])
