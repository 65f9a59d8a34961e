"""shaders/normals/: each kernel alone against its float64 twin (tsplus_wgpu.reference.normals).
The whole normal-loss chain is tested in tests/train/test_normals.py."""

import numpy as np
import pytest
from scenes import f32_exact, random_scene

from tsplus_wgpu.kernels.normals import NormalAccumulate, NormalBackward, NormalModel
import tsplus_wgpu.reference.normals as twin
from scenes import submit as _run, rel_error as _rel

W = H = 32


def _scene(seed, ties=False):
    model, cam = f32_exact(*random_scene(seed, W, H, sheets=3, points_per_sheet=8, sh_k=1))
    if ties:    # many tied opacities: the minimum goes to the lowest vertex index
        rng = np.random.default_rng(seed)
        model.opacity[:] = rng.choice([0.25, 0.5, 0.75], size=model.num_vertices)
    return model, cam


def _upload_model(ctx, model):
    return (ctx.upload(model.positions.astype(np.float32)), ctx.upload(model.triangles.astype(np.uint32)),
            ctx.upload(model.opacity.astype(np.float32)))


@pytest.mark.parametrize("seed", [1, 2])
def test_normal_model(ctx, seed):
    model, cam = _scene(seed)
    m, n = model.num_triangles, model.num_vertices
    k = NormalModel(ctx)
    pos, sh, op = ctx.buffer(36 * m), ctx.buffer(36 * m), ctx.buffer(12 * m)
    _run(ctx, lambda enc: k(enc, k.params(cam, m, n), *_upload_model(ctx, model), pos, sh, op, m))
    want = twin.normal_model(model, cam)
    np.testing.assert_array_equal(ctx.read(pos, np.float32, 9 * m).reshape(3 * m, 3), want.positions)
    np.testing.assert_array_equal(ctx.read(op, np.float32, 3 * m), want.opacity)
    got_sh = ctx.read(sh, np.float32, 9 * m).reshape(3 * m, 1, 3)
    assert _rel(got_sh, want.sh) <= 2e-6
    assert np.abs(want.sh).max() > 0.5                    # unit normals / (2 SH_C0)


@pytest.mark.parametrize("seed,ties", [(1, False), (2, True)])
def test_normal_backward(ctx, seed, ties):
    model, cam = _scene(seed, ties)
    m, n = model.num_triangles, model.num_vertices
    rng = np.random.default_rng(seed)
    v_pos = rng.normal(size=(3 * m, 3)).astype(np.float32)
    v_sh = rng.normal(size=(3 * m, 1, 3)).astype(np.float32)
    v_op = rng.normal(size=3 * m).astype(np.float32)
    params = NormalModel(ctx).params(cam, m, n)
    k = NormalBackward(ctx)
    vals = ctx.buffer(48 * m)
    _run(ctx, lambda enc: k(enc, params, *_upload_model(ctx, model), ctx.upload(v_pos), ctx.upload(v_sh),
                            ctx.upload(v_op), vals, m))
    got = ctx.read(vals, np.float32, 12 * m).reshape(3 * m, 4)
    want = twin.normal_backward(model.positions, model.triangles, model.opacity, cam, v_pos, v_sh, v_op)
    assert _rel(got[:, :3], want[:, :3]) <= 1e-5
    assert _rel(got[:, 3], want[:, 3]) <= 1e-6
    np.testing.assert_array_equal(got[:, 3] != 0, want[:, 3] != 0)   # the same corner holds o_T's gradient
    assert np.count_nonzero(want[:, 3]) == m              # o_T's gradient at one corner per triangle
    # a dropped path is far outside the tolerance
    for paths in (("alpha",), ("normal",)):
        mutant = twin.normal_backward(model.positions, model.triangles, model.opacity, cam, v_pos, v_sh, v_op, paths)
        assert _rel(got[:, :3], mutant[:, :3]) > 1e-2, paths


def test_normal_accumulate(ctx):
    model, cam = _scene(3)
    n = model.num_vertices
    rng = np.random.default_rng(3)
    sums = rng.normal(size=(n, 4)).astype(np.float32)
    v_pos0 = rng.normal(size=(n, 3)).astype(np.float32)
    v_op0 = rng.normal(size=n).astype(np.float32)
    params = NormalModel(ctx).params(cam, model.num_triangles, n, weight=0.05)
    k = NormalAccumulate(ctx)
    bp, bo = ctx.upload(v_pos0), ctx.upload(v_op0)
    _run(ctx, lambda enc: k(enc, params, ctx.upload(sums), bp, bo, n))
    want_p, want_o = twin.normal_accumulate(sums, v_pos0, v_op0, 0.05)
    np.testing.assert_allclose(ctx.read(bp, np.float32, 3 * n).reshape(n, 3), want_p, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(ctx.read(bo, np.float32, n), want_o, rtol=1e-6, atol=1e-7)
    assert np.abs(want_p - v_pos0).max() > 1e-2 and np.abs(want_o - v_op0).max() > 1e-2   # it adds something
