import numpy as np
import pytest

from tsplus_wgpu.train.optim import Adam, adam_reference


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
def test_adam_vs_twin(ctx, adam, n, max_dim):
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
        rp, rm, rv = adam_reference(rp, g, rm, rv, lr, step)
    assert _rel(ctx.read(bp, np.float32, n), rp) <= 1e-6
    assert _rel(ctx.read(bm, np.float32, n), rm) <= 1e-6
    assert _rel(ctx.read(bv, np.float32, n), rv) <= 1e-6


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
    e1 = adam_reference(p[100:400], g[100:400], z[:300], z[:300], 0.01, 1)[0]
    e2 = adam_reference(p[600:800], g[600:800], z[:200], z[:200], 0.5, 4)[0]
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
        adam_reference(np.zeros(1), np.zeros(1), np.zeros(1), np.zeros(1), 0.1, 0)
