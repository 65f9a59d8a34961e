"""shaders/optim/: each kernel alone against its float64 twin (tsplus_wgpu.reference.optim):
train_activate, train_grads, opacity_reg_count and opacity_reg_scale, depth_scale, adam."""

import numpy as np
import pytest

from tsplus_wgpu.gpu.stage import Scratch
from tsplus_wgpu.render.device_model import corner_order
from tsplus_wgpu.kernels.optim import Adam, DepthScale, OpacityRegCount, OpacityRegGradient, OpacityRegScale, TrainActivate, TrainGrads
import tsplus_wgpu.reference.optim as twin
from scenes import submit as _run


@pytest.mark.parametrize("n", [1, 300, 777])
@pytest.mark.parametrize("reinvert", [False, True])
def test_train_activate(ctx, n, reinvert):
    rng = np.random.default_rng(n)
    w = rng.normal(scale=3.0, size=n).astype(np.float32)
    w[:3] = [-30.0, 0.0, 30.0][: min(3, n)]
    floor, floor_old = (0.35, 0.1) if reinvert else (0.2, None)
    bw, bo = ctx.upload(w), ctx.buffer(4 * n)
    stage = TrainActivate(ctx)
    _run(ctx, lambda enc: stage(enc, bw, bo, n, floor, floor_old))
    o_ref, w_ref = twin.train_activate(w, floor, floor_old)
    np.testing.assert_allclose(ctx.read(bo, np.float32, n), o_ref, rtol=0, atol=2e-6)
    w_dev = ctx.read(bw, np.float32, n)
    if reinvert:
        # the logit is ill-conditioned where q is near 0 or 1: compare opacities there
        o_dev = floor + (1 - floor) * twin.sigmoid(w_dev)
        np.testing.assert_allclose(o_dev, o_ref, atol=3e-6)
        mid = np.abs(w_ref) < 5
        np.testing.assert_allclose(w_dev[mid], w_ref[mid], atol=2e-4)
    else:
        np.testing.assert_array_equal(w_dev, w)


@pytest.mark.parametrize("n,k,active,chunk", [(5, 1, 1, None), (300, 16, 4, None), (513, 9, 9, None),
                                              (1000, 16, 4, 2**14), (700, 9, 1, 8192)])
@pytest.mark.parametrize("use_reg", [False, True])
def test_train_grads(ctx, monkeypatch, n, k, active, chunk, use_reg):
    """``chunk``: bindings of at most that many bytes, so the vertices go in ranges (gpu/chunks.py)."""
    import tsplus_wgpu.gpu.chunks as chunks
    monkeypatch.setattr(chunks, "CHUNK_BYTES", chunk)
    if chunk:
        assert len(chunks.item_chunks(ctx, n, [12 * k, 16])) >= 3
    rng = np.random.default_rng(7 * n + k)
    w = rng.normal(scale=2.0, size=n).astype(np.float32)
    vsh = rng.normal(size=(n, k, 3)).astype(np.float32)
    vo = rng.normal(size=n).astype(np.float32)
    reg = np.zeros((n, 4), np.float32)
    reg[:, 0] = rng.normal(size=n)
    floor = 0.3
    bvsh, bvw = ctx.upload(vsh), ctx.buffer(4 * n)
    stage = TrainGrads(ctx)
    _run(ctx, lambda enc: stage(enc, ctx.upload(w), bvsh, ctx.upload(vo), ctx.upload(reg), bvw,
                                n, k, active, floor, use_reg))
    vsh_ref, vw_ref = twin.train_grads(w, vsh, vo, floor, active, reg[:, 0] if use_reg else None)
    got = ctx.read(bvsh, np.float32, 3 * n * k).reshape(n, k, 3)
    np.testing.assert_array_equal(got, vsh_ref.astype(np.float32))
    assert not np.any(got[:, active:]) and np.all(got[:, :active] == vsh[:, :active])
    np.testing.assert_allclose(ctx.read(bvw, np.float32, n), vw_ref, rtol=1e-5, atol=1e-7)


def _reg_case(m):
    rng = np.random.default_rng(m)
    n = max(3, m // 3)
    tri = np.stack([rng.choice(n, 3, replace=False) for _ in range(m)]).astype(np.int64)
    op = rng.choice([0.2, 0.5, 0.9], size=n).astype(np.float32)   # many ties
    return tri, op, n


@pytest.mark.parametrize("m", [1, 50, 5000])
def test_opacity_reg_count(ctx, m):
    """The counts exactly (an integer stage), added to what the buffer holds."""
    tri, op, n = _reg_case(m)
    stage = OpacityRegCount(ctx)
    counts = ctx.upload(np.full(n, 7, np.uint32))          # added to: 7 + the counts
    _run(ctx, lambda enc: stage(enc, ctx.upload(tri.astype(np.uint32)), ctx.upload(op), counts, m))
    got = ctx.read(counts, np.uint32, n).astype(np.int64) - 7
    want = twin.opacity_reg_count(tri, op, n)
    np.testing.assert_array_equal(got, want)
    assert want.sum() == m                                # one corner per triangle (ties resolved)
    if m >= 50:                                           # the ties do decide: not the first corner's vertex
        assert not np.array_equal(want, np.bincount(tri[:, 0], minlength=n))


@pytest.mark.parametrize("chunk", [None, 2**10])
def test_opacity_reg_scale(ctx, monkeypatch, chunk):
    """``chunk``: bindings of at most that many bytes: the vertices in ranges."""
    import tsplus_wgpu.gpu.chunks as chunks
    monkeypatch.setattr(chunks, "CHUNK_BYTES", chunk)
    n = 3000
    counts = np.random.default_rng(1).integers(0, 40, n).astype(np.uint32)
    counts[:3] = (0, 1, 2**24 - 1)                        # the largest count f32 holds exactly
    per = 1.9e-6 / 12345
    out = ctx.upload(np.full((n, 4), 5.0, np.float32))
    _run(ctx, lambda enc: OpacityRegScale(ctx)(enc, ctx.upload(counts), out, n, per))
    got = ctx.read(out, np.float32, 4 * n).reshape(n, 4)
    want = twin.opacity_reg_scale(counts, per)
    np.testing.assert_allclose(got, want, rtol=2e-7, atol=0)


@pytest.mark.parametrize("m,chunk", [(1, None), (50, None), (5000, None), (5000, 2**10)])
def test_opacity_reg_gradient_matches_twin(ctx, monkeypatch, m, chunk):
    """``chunk``: bindings of at most that many bytes: the per-vertex scale in ranges of vertices.
    The output's stale values must go: it is filled with garbage first, and the run repeated."""
    import tsplus_wgpu.gpu.chunks as chunks
    monkeypatch.setattr(chunks, "CHUNK_BYTES", chunk)
    tri, op, n = _reg_case(m)
    reg = OpacityRegGradient(ctx, Scratch(ctx))
    out = ctx.upload(np.full((n, 4), 3.0, np.float32))
    btri, bop = ctx.upload(tri.astype(np.uint32)), ctx.upload(op)
    for _ in range(2):                                    # the counts start from zero each time
        _run(ctx, lambda enc: reg.record(enc, btri, bop, out, 1.9e-6, n, m))
    got = ctx.read(out, np.float32, 4 * n).reshape(n, 4)
    want = twin.opacity_reg_gradient(tri, op, 1.9e-6, n)
    np.testing.assert_allclose(got[:, 0], want, rtol=2e-7, atol=0)
    assert not np.any(got[:, 1:])
    # the gather order the backward takes: corners sorted by vertex, stable
    bkeys, bindex = corner_order(ctx, tri)
    keys = ctx.read(bkeys, np.uint32, 3 * m)
    index = ctx.read(bindex, np.uint32, 3 * m)
    np.testing.assert_array_equal(keys, tri.reshape(-1)[index])
    np.testing.assert_array_equal(index, np.argsort(tri.reshape(-1), kind="stable"))


# ---------------------------------------------------------------------- adam

@pytest.fixture(scope="module")
def adam(ctx):
    return Adam(ctx)


def _state(ctx, p):
    n = len(p)
    bp, bm, bv = ctx.upload(p.astype(np.float32)), ctx.buffer(4 * n), ctx.buffer(4 * n)
    enc = ctx.device.create_command_encoder()
    enc.clear_buffer(bm)
    enc.clear_buffer(bv)
    ctx.queue.submit([enc.finish()])
    return bp, bm, bv


def _rel(a, b):
    return float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-300)) if len(b) else 0.0


@pytest.mark.parametrize("n,max_dim", [(0, None), (1, None), (255, None), (257, None), (70_001, None),
                                       (3_000_000, None), (3_000_000, 1000), (100_000, 7)])
def test_adam(ctx, adam, n, max_dim):
    """Several steps with changing lr; max_dim forces the 2-D grid (3M elements -> 12 x 977 groups)."""
    rng = np.random.default_rng(n)
    p = rng.standard_normal(n).astype(np.float32)
    bp, bm, bv = _state(ctx, p)
    rp, rm, rv = p.astype(np.float64), np.zeros(n), np.zeros(n)
    steps = 3 if n > 100_000 else 6
    for step in range(1, steps + 1):
        g = (rng.standard_normal(n) * 10.0 ** rng.uniform(-3, 1)).astype(np.float32)
        lr = 1e-3 * step
        enc = ctx.device.create_command_encoder()
        adam.record(enc, bp, ctx.upload(g), bm, bv, n, lr, step, max_dim=max_dim)
        ctx.queue.submit([enc.finish()])
        rp, rm, rv = twin.adam(rp, g, rm, rv, lr, step)
    assert _rel(ctx.read(bp, np.float32, n), rp) <= 1e-6
    assert _rel(ctx.read(bm, np.float32, n), rm) <= 1e-6
    assert _rel(ctx.read(bv, np.float32, n), rv) <= 1e-6


@pytest.mark.parametrize("n,k,offset,max_binding", [(500, 16, 0, None), (500, 16, 0, 4096), (333, 9, 48, 2048),
                                                      (64, 1, 0, 1024)])
def test_adam_two_rates_in_ranges(ctx, adam, n, k, offset, max_binding):
    """The SH [N, K, 3] as one group: the first 3 of every 3K elements at lr (DC), the rest at
    lr_tail; with max_binding the buffers go in ranges, each bound from a 256-byte boundary."""
    size = offset + 3 * n * k
    rng = np.random.default_rng(n + k)
    p = rng.standard_normal(size).astype(np.float32)
    bp, bm, bv = _state(ctx, p)
    rp, rm, rv = p[offset:].astype(np.float64), np.zeros(3 * n * k), np.zeros(3 * n * k)
    lr = np.where(np.arange(3 * n * k) % (3 * k) < 3, 0.05, 0.0025)
    for step in (1, 2, 3):
        g = rng.standard_normal(size).astype(np.float32)
        enc = ctx.device.create_command_encoder()
        adam.record(enc, bp, ctx.upload(g), bm, bv, 3 * n * k, 0.05, step, offset=offset, lr_tail=0.0025,
                    period=3 * k, head=3, max_binding=max_binding)
        ctx.queue.submit([enc.finish()])
        rp, rm, rv = twin.adam(rp, g[offset:], rm, rv, lr, step)
        if step == 1:   # the first step moves every element by its own lr: DC 20x the rest
            moved = np.abs(ctx.read(bp, np.float32, size)[offset:] - p[offset:]).reshape(n, k, 3)
            np.testing.assert_allclose(moved, lr.reshape(n, k, 3), rtol=1e-3)
    out = ctx.read(bp, np.float32, size)
    assert _rel(out[offset:], rp) <= 1e-6
    assert np.array_equal(out[:offset], p[:offset])               # before the group: untouched


@pytest.mark.parametrize("n,c,reach", [(1, 1, 1.0), (300, 7, 1.0), (5000, 60, 0.25)])
def test_depth_scale(ctx, n, c, reach):
    """Vertices from on a camera centre (scale 0) to far beyond reach (1)."""
    rng = np.random.default_rng(n + c)
    centres = rng.normal(scale=2.0, size=(c, 3))
    p = centres[rng.integers(0, c, n)] + rng.normal(size=(n, 3)) * 10.0 ** rng.uniform(-3, 1, (n, 1))
    p[0] = centres[0]
    p = p.astype(np.float32)
    stage, out = DepthScale(ctx), ctx.buffer(4 * n)
    _run(ctx, lambda enc: stage(enc, ctx.upload(p), stage.centres(centres.astype(np.float32)), out, n, c, reach))
    got, ref = ctx.read(out, np.float32, n), twin.depth_scale(p, centres.astype(np.float32), reach)
    np.testing.assert_allclose(got, ref, rtol=1e-5, atol=1e-6)
    assert got[0] == 0.0 and (n == 1 or 0 < (ref < 1).sum() < n)


@pytest.mark.parametrize("n,offset,max_binding", [(700, 0, None), (700, 0, 1024), (333, 48, 2048), (2, 0, None)])
def test_adam_scale_per_vertex(ctx, adam, n, offset, max_binding):
    """The positions' step by depth: [N, 3] elements, one scale per 3 (per vertex), in ranges with
    max_binding; a scale of 0 stops its vertex, and every step is the twin's."""
    size = offset + 3 * n
    rng = np.random.default_rng(n + offset)
    p = rng.standard_normal(size).astype(np.float32)
    sc = rng.uniform(0.0, 1.0, n).astype(np.float32)
    sc[0] = 0.0
    bp, bm, bv = _state(ctx, p)
    rp, rm, rv = p[offset:].astype(np.float64), np.zeros(3 * n), np.zeros(3 * n)
    for step in (1, 2, 3):
        g = rng.standard_normal(size).astype(np.float32)
        enc = ctx.device.create_command_encoder()
        adam.record(enc, bp, ctx.upload(g), bm, bv, 3 * n, 0.01, step, offset=offset, max_binding=max_binding,
                    scale=ctx.upload(sc), stride=3)
        ctx.queue.submit([enc.finish()])
        rp, rm, rv = twin.adam(rp, g[offset:], rm, rv, 0.01, step, scale=sc, stride=3)
        if step == 1:   # the first step moves every element by its lr times its vertex's scale
            moved = np.abs(ctx.read(bp, np.float32, size)[offset:] - p[offset:]).reshape(n, 3)
            np.testing.assert_allclose(moved, 0.01 * np.repeat(sc[:, None], 3, 1), rtol=2e-3, atol=2e-7)
    out = ctx.read(bp, np.float32, size)
    assert _rel(out[offset:], rp) <= 1e-6
    assert np.array_equal(out[offset:offset + 3], p[offset:offset + 3])      # scale 0: not moved
    assert np.array_equal(out[:offset], p[:offset])


def test_adam_defaults_are_the_shaders():
    assert (twin.BETA1, twin.BETA2, twin.ADAM_EPS) == (0.9, 0.999, 1e-15)


def test_adam_groups_share_a_buffer(ctx, adam):
    """Two groups (different lr, different step counts) in one buffer; nothing outside is touched."""
    rng = np.random.default_rng(7)
    n = 1000
    p = rng.standard_normal(n).astype(np.float32)
    g = rng.standard_normal(n).astype(np.float32)
    bp, bm, bv = _state(ctx, p)
    bg = ctx.upload(g)
    enc = ctx.device.create_command_encoder()
    adam.record(enc, bp, bg, bm, bv, 300, 0.01, 1, offset=100)
    adam.record(enc, bp, bg, bm, bv, 200, 0.5, 4, offset=600)
    ctx.queue.submit([enc.finish()])
    out = ctx.read(bp, np.float32, n)
    z = np.zeros(n)
    e1 = twin.adam(p[100:400], g[100:400], z[:300], z[:300], 0.01, 1)[0]
    e2 = twin.adam(p[600:800], g[600:800], z[:200], z[:200], 0.5, 4)[0]
    assert _rel(out[100:400], e1) <= 1e-6 and _rel(out[600:800], e2) <= 1e-6
    untouched = np.r_[0:100, 400:600, 800:1000]
    assert np.array_equal(out[untouched], p[untouched])
    assert np.all(ctx.read(bm, np.float32, n)[untouched] == 0)


def test_adam_zero_grad_and_first_step(ctx, adam):
    n = 513
    p = np.random.default_rng(8).standard_normal(n).astype(np.float32)
    bp, bm, bv = _state(ctx, p)
    g = np.zeros(n, np.float32)
    g[::2] = np.random.default_rng(9).standard_normal(len(g[::2]))
    enc = ctx.device.create_command_encoder()
    adam.record(enc, bp, ctx.upload(g), bm, bv, n, 0.1, 1)
    ctx.queue.submit([enc.finish()])
    out = ctx.read(bp, np.float32, n)
    assert np.array_equal(out[1::2], p[1::2])                          # zero gradient: no move, no NaN
    np.testing.assert_allclose(out[::2], p[::2] - 0.1 * np.sign(g[::2]), rtol=0, atol=1e-6)   # |step| = lr


def test_adam_bad_arguments(ctx, adam):
    b = ctx.buffer(64)
    enc = ctx.device.create_command_encoder()
    with pytest.raises(ValueError):
        adam.record(enc, b, b, b, b, 17, 0.1, 1)            # buffer too small
    with pytest.raises(ValueError):
        adam.record(enc, b, b, b, b, 4, 0.1, 0)             # step is 1-based
    with pytest.raises(ValueError):
        adam.record(enc, b, b, b, b, 16, 0.1, 1, scale=ctx.buffer(16), stride=3)   # 6 scales needed, 4 held
    with pytest.raises(ValueError):
        adam.record(enc, b, b, b, b, 4, 0.1, 1, scale=b, stride=0)
    with pytest.raises(ValueError):
        twin.adam(np.zeros(1), np.zeros(1), np.zeros(1), np.zeros(1), 0.1, 0)
