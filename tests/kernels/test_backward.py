"""Kernels of shaders/backward/, each alone on uploaded inputs, against its float64 twin
(tsplus_wgpu/reference/backward.py). Inputs come from a forward pass of small random
scenes (read back, then uploaded again), so they are the data the kernels see in training.
Integer outputs (the pixels' last pair, work counters) are compared exactly, floats with
tolerances scaled by each output's magnitude, tight enough to fail when a term is dropped."""

import importlib

import numpy as np
import pytest
from scenes import f32_exact, random_scene

from tsplus_wgpu.kernels.project import frame_params
from tsplus_wgpu.kernels.backward import (NSTAT, BackwardPrepare, ProjectBackward, RasterizeBackward,
                                          RasterizeBackwardGpu, VertexBackward)
from scenes import submit as run
# (the package's attribute ``backward`` is the whole-backward twin function, so the module by name)
twin = importlib.import_module("tsplus_wgpu.reference.backward")

BG = (0.1, 0.2, 0.3)
#: (seed, width, height, sigma): a 2x2-tile view and a wider one with more overlap
CASES = [(11, 32, 32, 1.0), (8, 48, 40, 0.7)]


def sizes(model, num_pairs):
    return dict(num_vertices=model.num_vertices, num_triangles=model.num_triangles, sh_k=model.sh_size,
                num_pairs=num_pairs)


_FORWARD = {}


def forward_data(renderer, case):
    """The forward's outputs the backward kernels read, as host arrays."""
    if case not in _FORWARD:
        seed, w, h, sigma = case
        model, cam = f32_exact(*random_scene(seed, w, h, sheets=4, points_per_sheet=12, sh_k=4))
        res = renderer.forward(model, cam, sigma, BG)
        c, b, m, n = renderer.ctx, res.buffers, model.num_triangles, model.num_vertices
        rng = np.random.default_rng(seed)
        v_out = rng.normal(size=(h * w, 4)).astype(np.float32)
        _FORWARD[case] = dict(
            model=model, cam=cam, sigma=sigma, num_pairs=res.num_pairs, v_out=v_out,
            image=res.image, final_t=res.transmittance, n_contrib=c.read(b["n_contrib"], np.uint32, 2 * h * w),
            tris=c.read(b["tris"], np.float32, 24 * m), ranges=res.tile_ranges(), pair_tris=res.pairs()[1],
            pixel_rects=c.read(b["pixel_rects"], np.int32, 4 * m), colors=c.read(b["colors"], np.float32, 4 * n))
    return _FORWARD[case]


def assert_scaled(got, want, rtol, what):
    """|got - want| <= rtol * max|want| per output column (the last axis)."""
    got, want = np.asarray(got, np.float64), np.asarray(want, np.float64)
    scale = np.abs(want).reshape(-1, want.shape[-1]).max(axis=0)
    err = np.abs(got - want).reshape(-1, want.shape[-1]).max(axis=0)
    bad = err > rtol * np.maximum(scale, 1e-30)
    assert not bad.any(), f"{what}: column errors {err[bad]} > {rtol} x scales {scale[bad]}"


def prepared(d):
    """backward_prepare's twin output as the kernel writes it: [H*W] vec4 (T, acc, Z, last bits)."""
    state, last = twin.backward_prepare(d["image"], d["final_t"], d["n_contrib"], d["v_out"])
    out = np.zeros((state.shape[0], 4), np.float32)
    out[:, :3] = state
    out[:, 3] = last.view(np.float32)
    return out, state, last


@pytest.mark.parametrize("case", CASES)
def test_backward_prepare(renderer, case):
    c, d = renderer.ctx, forward_data(renderer, case)
    k = BackwardPrepare(c)
    npix = d["final_t"].size
    bufs = {name: c.upload(np.ascontiguousarray(d[name]), name) for name in ("image", "final_t", "n_contrib", "v_out")}
    state = c.buffer(16 * npix, "state")
    params = frame_params(k, d["cam"], d["sigma"], BG, **sizes(d["model"], d["num_pairs"]))
    run(c, lambda enc: k(enc, params, bufs["image"], bufs["final_t"], bufs["n_contrib"], bufs["v_out"], state, npix))
    got = c.read(state, np.float32, 4 * npix).reshape(npix, 4)
    _, want, last = prepared(d)
    np.testing.assert_array_equal(got[:, 3].view(np.uint32), last)
    np.testing.assert_array_equal(got[:, :2], want[:, :2])
    assert_scaled(got[:, 2:3], want[:, 2:3], 1e-6, "Z")


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("rounds_per_pass", [None, 1])
def test_rasterize_backward(renderer, layout_renderers, case, rounds_per_pass):
    """The replay and its 19 statistics per pair; in one pass per tile, and in passes of one
    round (the state carried between dispatches)."""
    check_backward(layout_renderers["cpu"].ctx, RasterizeBackward, forward_data(renderer, case), rounds_per_pass)


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("rounds_per_pass", [None, 1])
def test_rasterize_backward_gpu(renderer, layout_renderers, case, rounds_per_pass):
    """The GPU layout (one invocation a pixel): the same checks, and the CPU layout's work
    counts and last pairs exactly, its floats within rounding (the sums go in another order)."""
    d = forward_data(renderer, case)
    got = check_backward(layout_renderers["pixel"].ctx, RasterizeBackwardGpu, d, rounds_per_pass)
    other = check_backward(layout_renderers["cpu"].ctx, RasterizeBackward, d, None)
    np.testing.assert_array_equal(got[2], other[2])
    np.testing.assert_array_equal(got[0][:, 3].view(np.uint32), other[0][:, 3].view(np.uint32))
    assert_scaled(got[0][:, :3], other[0][:, :3], 1e-6, "state against the CPU layout")
    assert_scaled(got[1], other[1], 1e-5, "partials against the CPU layout")


def check_backward(c, cls, d, rounds_per_pass):
    """``cls`` on ``c`` against the twin; returns (state [H*W, 4], partials [P, NSTAT], work)."""
    k = cls(c)
    if rounds_per_pass is not None:
        k.rounds_per_pass = rounds_per_pass
    cam, P = d["cam"], d["num_pairs"]
    tx, ty = (cam.width + 15) // 16, (cam.height + 15) // 16
    state0, st, last = prepared(d)
    max_range = int((d["ranges"][:, 1] - d["ranges"][:, 0]).max())
    if rounds_per_pass is not None:
        assert max_range > 2 * k.pairs_per_round     # three passes or more
    bufs = {name: c.upload(np.ascontiguousarray(d[name]), name) for name in ("ranges", "pair_tris", "tris", "v_out")}
    state, partials, work = c.upload(state0, "state"), c.buffer(4 * NSTAT * P, "partials"), c.buffer(16, "work")
    params = frame_params(k, cam, d["sigma"], BG, **sizes(d["model"], P))
    run(c, lambda enc: k(enc, params, bufs["ranges"], bufs["pair_tris"], bufs["tris"], bufs["v_out"], state, partials,
                         work, tx, ty, max_range))
    want_p, want_s, want_w = twin.rasterize_backward(d["tris"], d["ranges"], d["pair_tris"], d["v_out"], st, last,
                                                     cam.width, cam.height, tx, d["sigma"])
    got_s = c.read(state, np.float32, state0.size).reshape(-1, 4)
    got_w = c.read(work, np.uint32, 3)
    np.testing.assert_array_equal(got_w, want_w)
    np.testing.assert_array_equal(got_s[:, 3].view(np.uint32), last)
    assert_scaled(got_s[:, :3], want_s, 1e-5, "state (T, acc, Z)")
    got_p = c.read(partials, np.float32, NSTAT * P).reshape(P, NSTAT)
    assert np.abs(want_p[:, :19]).max(axis=0).min() > 0     # every statistic is exercised
    assert_scaled(got_p, want_p, 2e-5, "partials")
    return got_s, got_p, got_w


@pytest.mark.parametrize("case", CASES)
def test_rasterize_backward_in_pair_windows(renderer, case):
    """Window by window (the tiles whose first pair lies in each window, pair p's statistics
    at p - lo): every pair's statistics and every pixel's state as in one dispatch, the work
    counters summed over the windows."""
    from tsplus_wgpu.render.backward import pair_windows
    c, d = renderer.ctx, forward_data(renderer, case)
    k = RasterizeBackward(c)
    cam, P = d["cam"], d["num_pairs"]
    tx, ty = (cam.width + 15) // 16, (cam.height + 15) // 16
    state0, st, last = prepared(d)
    max_range = int((d["ranges"][:, 1] - d["ranges"][:, 0]).max())
    windows = pair_windows(P, max_range, max_range + P // 3)
    assert len(windows) >= 3
    bufs = {name: c.upload(np.ascontiguousarray(d[name]), name) for name in ("ranges", "pair_tris", "tris", "v_out")}
    state, work = c.upload(state0, "state"), c.buffer(16, "work")
    params = frame_params(k, cam, d["sigma"], BG, **sizes(d["model"], P))
    got_p = np.zeros((P, NSTAT), np.float32)
    for i, (lo, hi, length) in enumerate(windows):
        partials = c.buffer(4 * NSTAT * length, "partials")
        run(c, lambda enc: k(enc, params, bufs["ranges"], bufs["pair_tris"], bufs["tris"], bufs["v_out"], state,
                             partials, work, tx, ty, max_range, window=(lo, hi), clear=i == 0))
        part = c.read(partials, np.float32, NSTAT * length).reshape(length, NSTAT)
        starts = d["ranges"][:, 0]
        for t0, t1 in d["ranges"][(starts >= lo) & (starts < hi) & (d["ranges"][:, 1] > starts)]:
            got_p[t0:t1] = part[t0 - lo:t1 - lo]
        outside = np.ones(length, bool)      # pairs of later windows' tiles stay zero here
        for t0, t1 in d["ranges"][(starts >= lo) & (starts < hi)]:
            outside[t0 - lo:t1 - lo] = False
        assert not part[outside].any()
    want_p, want_s, want_w = twin.rasterize_backward(d["tris"], d["ranges"], d["pair_tris"], d["v_out"], st, last,
                                                     cam.width, cam.height, tx, d["sigma"])
    np.testing.assert_array_equal(c.read(work, np.uint32, 3), want_w)
    got_s = c.read(state, np.float32, state0.size).reshape(-1, 4)
    np.testing.assert_array_equal(got_s[:, 3].view(np.uint32), last)
    assert_scaled(got_s[:, :3], want_s, 1e-5, "state (T, acc, Z)")
    assert_scaled(got_p, want_p, 2e-5, "partials")


@pytest.mark.parametrize("case", CASES)
def test_project_backward(renderer, case):
    """The chain rule per triangle, on the statistics of its pairs (the twin's partials summed)."""
    c, d = renderer.ctx, forward_data(renderer, case)
    k = ProjectBackward(c)
    model, cam = d["model"], d["cam"]
    m = model.num_triangles
    _, st, last = prepared(d)
    tx = (cam.width + 15) // 16
    partials = twin.rasterize_backward(d["tris"], d["ranges"], d["pair_tris"], d["v_out"], st, last, cam.width,
                                       cam.height, tx, d["sigma"])[0]
    stats = np.zeros((m, NSTAT))
    np.add.at(stats, d["pair_tris"], partials)
    stats = stats.astype(np.float32)
    host = dict(positions=model.positions.astype(np.float32), triangles=model.triangles.astype(np.uint32),
                opacities=model.opacity.astype(np.float32), colors=d["colors"], tris=d["tris"],
                pixel_rects=d["pixel_rects"], tri_stats=stats)
    bufs = {name: c.upload(np.ascontiguousarray(a), name) for name, a in host.items()}
    out = c.buffer(32 * 3 * m, "corner_grads")
    params = frame_params(k, cam, d["sigma"], BG, **sizes(model, d["num_pairs"]))
    run(c, lambda enc: k(enc, params, *bufs.values(), out, m))
    got = c.read(out, np.float32, 24 * m).reshape(3 * m, 2, 4)
    want = twin.project_backward(*host.values(), cam)
    drawn = np.repeat((d["pixel_rects"].reshape(m, 4)[:, 0] <= d["pixel_rects"].reshape(m, 4)[:, 2]), 3)
    assert drawn.any() and not got[~drawn].any()
    np.testing.assert_array_equal(got[:, 0, 3], want[:, 0, 3])           # dL/d opacity: moved, not computed
    assert_scaled(got[:, 0, :3], want[:, 0, :3], 2e-5, "dL/d colour")
    assert_scaled(got[:, 1, :3], want[:, 1, :3], 5e-5, "dL/d position")
    assert not got[:, 1, 3].any()


@pytest.mark.parametrize("sh_k", [1, 4, 16])
def test_vertex_backward(renderer, sh_k):
    c = renderer.ctx
    model, cam = f32_exact(*random_scene(5, 40, 30, sheets=3, points_per_sheet=40, sh_k=sh_k))
    n = model.num_vertices
    rng = np.random.default_rng(sh_k)
    sums = rng.normal(size=(n, 2, 4)).astype(np.float32)
    k = VertexBackward(c)
    pos, sh = model.positions.astype(np.float32), model.sh.astype(np.float32)
    bufs = [c.upload(a, name) for a, name in ((pos, "positions"), (sh, "sh"), (sums, "vertex_sums"))]
    outs = [c.buffer(nb, name) for nb, name in ((12 * n, "v_positions"), (12 * n * sh_k, "v_sh"), (4 * n, "v_opacity"))]
    params = frame_params(k, cam, 1.0, BG, **sizes(model, 0))
    run(c, lambda enc: k(enc, params, *bufs, *outs, n))
    want = twin.vertex_backward(pos, sh, sums, cam.center)
    got = [c.read(o, np.float32, w.size).reshape(w.shape) for o, w in zip(outs, want)]
    assert_scaled(got[0], want[0], 1e-5, "v_positions")
    assert_scaled(got[1].reshape(n, -1), want[1].reshape(n, -1), 1e-5, "v_sh")
    np.testing.assert_array_equal(got[2], want[2])
