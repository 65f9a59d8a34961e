"""Kernels of shaders/reduce/, each alone on uploaded inputs, against its float64 twin
(tsplus_wgpu/reference/reduce.py): max_reduce exactly; segment_up / segment_down / the
composed SegmentSum: keys exactly, sums to float32 rounding (and bit for bit against the
twin run in float32, which adds in the kernels' order); segment_gather bit for bit against
SegmentSum itself."""

import numpy as np
import pytest

from tsplus_wgpu.kernels.reduce import (MaxReduce, SegmentDown, SegmentGather, SegmentSum, SegmentUp, key_spans,
                                        segment_levels)
from tsplus_wgpu.gpu import Scratch
from tsplus_wgpu.reference import reduce as twin
from scenes import submit as _run

CHUNK = twin.CHUNK


def _segments(seed, n, width, num_keys, run=None):
    """Sorted keys [n] (runs of random lengths, some keys absent), a permutation index [n]
    and values [n, width, 4] float32."""
    rng = np.random.default_rng(seed)
    if run is None:
        keys = np.sort(rng.integers(0, num_keys, n)).astype(np.uint32)
    else:                                   # runs of exactly `run` elements
        keys = (np.arange(n) // run).astype(np.uint32)
    index = rng.permutation(n).astype(np.uint32)
    vals = rng.normal(size=(n, width, 4)).astype(np.float32)
    return keys, index, vals


def _close(got, want, vals, n):
    """Sums of up to n float32 terms of size |vals|: float32 rounding allows ~n * eps * max|v|."""
    tol = 4 * max(n, 1) * np.finfo(np.float32).eps * float(np.abs(vals).max(initial=0))
    np.testing.assert_allclose(got, want, rtol=0, atol=tol)


@pytest.mark.parametrize("n", [1, 255, 256, 257, 5000])
def test_max_reduce(ctx, n):
    rng = np.random.default_rng(n)
    values = rng.integers(0, 2**32 - 1, n, dtype=np.uint64).astype(np.uint32)
    values_buf = ctx.upload(np.concatenate([values, np.full(3, 2**32 - 1, np.uint32)]), "values")   # beyond n: ignored
    result = ctx.buffer(16, "result")
    k = MaxReduce(ctx)
    _run(ctx, lambda enc: k(enc, values_buf, result, n))
    assert ctx.read(result, np.uint32, 1)[0] == twin.max_reduce(values, n)


@pytest.mark.parametrize("n,width,gather,num_keys,run", [(1000, 5, True, 40, None), (3 * CHUNK + 7, 2, False, 5, None),
                                                         (777, 1, True, 0, 1), (640, 2, True, 0, 200)])
def test_segment_up(ctx, n, width, gather, num_keys, run):
    keys, index, vals = _segments(n, n, width, num_keys, run)
    nc = (n + CHUNK - 1) // CHUNK
    bufs = [ctx.upload(a, name) for a, name in ((keys, "keys_in"), (index, "index"), (vals, "vals_in"))]
    keys_out, vals_out = ctx.buffer(4 * nc, "keys_out"), ctx.buffer(16 * width * nc, "vals_out")
    k = SegmentUp(ctx)
    _run(ctx, lambda enc: k(enc, *bufs, keys_out, vals_out, n, width, gather))
    want_k, want_v = twin.segment_up(keys, index, vals, n, width, gather)
    got_v = ctx.read(vals_out, np.float32, 4 * width * nc).reshape(nc, width, 4)
    np.testing.assert_array_equal(ctx.read(keys_out, np.uint32, nc), want_k)
    _close(got_v, want_v, vals, CHUNK)
    np.testing.assert_array_equal(got_v, twin.segment_up(keys, index, vals, n, width, gather, np.float32)[1])


@pytest.mark.parametrize("n,width,gather,top,num_keys,run", [
    (1000, 5, True, False, 40, None), (1000, 2, False, True, 40, None), (CHUNK, 1, True, True, 3, None),
    (640, 2, True, False, 0, 200)])
def test_segment_down(ctx, n, width, gather, top, num_keys, run):
    keys, index, vals = _segments(n + 1, n, width, num_keys, run)
    num_keys = int(keys.max()) + 1
    out0 = np.random.default_rng(1).normal(size=(num_keys, width, 4)).astype(np.float32)   # the coarser levels' totals
    bufs = [ctx.upload(a, name) for a, name in ((keys, "keys_in"), (index, "index"), (vals, "vals_in"))]
    out = ctx.upload(out0, "out")
    k = SegmentDown(ctx)
    _run(ctx, lambda enc: k(enc, *bufs, out, n, width, gather, top))
    got = ctx.read(out, np.float32, out0.size).reshape(out0.shape)
    _close(got, twin.segment_down(keys, index, vals, out0, n, width, gather, top), vals, n if top else CHUNK)
    np.testing.assert_array_equal(got, twin.segment_down(keys, index, vals, out0, n, width, gather, top, np.float32))


@pytest.mark.parametrize("n,width,num_keys,run", [(0, 2, 4, None), (50, 1, 7, None), (20000, 2, 300, None),
                                                  (9000, 5, 0, 9000), (CHUNK * CHUNK + 1, 1, 0, 3)])
def test_segment_sum(ctx, n, width, num_keys, run):
    """SegmentSum (segment_up levels, then segment_down from the coarsest) against the twin
    composed the same way, and against a plain per-key sum; keys without elements get zero."""
    keys, index, vals = _segments(n + 2, n, width, num_keys, run)
    num_keys = max(num_keys, int(keys.max(initial=0)) + 1) + 2
    ss = SegmentSum(ctx, Scratch(ctx), "test_sum")
    bufs = [ctx.upload(a if a.size else np.zeros(4, a.dtype), name) for a, name in ((keys, "keys"), (index, "index"),
                                                                                   (vals, "vals"))]
    out = ctx.buffer(16 * width * num_keys, "out")
    _run(ctx, lambda enc: ss.record(enc, *bufs, n, width, out))
    got = ctx.read(out, np.float32, 4 * width * num_keys).reshape(num_keys, width, 4)
    want = twin.segment_sum(keys, index, vals, n, width, num_keys)
    plain = np.zeros((num_keys, width, 4))
    np.add.at(plain, keys, vals[index].astype(np.float64))
    np.testing.assert_allclose(want, plain, rtol=0, atol=1e-9)
    _close(got, want, vals, max(np.bincount(keys).max(initial=0), 1) if n else 1)
    np.testing.assert_array_equal(got, twin.segment_sum(keys, index, vals, n, width, num_keys, np.float32))


@pytest.mark.parametrize("n,width,num_keys,chunk", [(20000, 2, 3000, 2**14), (9000, 5, 700, 2**13),
                                                    (5000, 1, 600, 2**11)])
def test_segment_sum_in_pages(ctx, monkeypatch, n, width, num_keys, chunk):
    """Values and sums larger than one binding (forced to ``chunk`` bytes, gpu/chunks.py): one
    pass per page of gathered values, each writing every page of keys through its own binding;
    against the twin within float32 rounding (the order of the additions is per page)."""
    import tsplus_wgpu.gpu.chunks as chunks
    keys, index, vals = _segments(n + 7, n, width, num_keys)
    num_keys = int(keys.max()) + 3
    monkeypatch.setattr(chunks, "CHUNK_BYTES", chunk)
    assert 16 * width * n > 2 * chunk and 16 * width * num_keys > chunk
    ss = SegmentSum(ctx, Scratch(ctx), "test_sum_pages")
    out = ctx.buffer(16 * width * num_keys, "out")
    bufs = [ctx.upload(a, name) for a, name in ((keys, "keys"), (index, "index"), (vals, "vals"))]
    _run(ctx, lambda enc: ss.record(enc, *bufs, n, width, out))
    got = ctx.read(out, np.float32, 4 * width * num_keys).reshape(num_keys, width, 4)
    want = twin.segment_sum(keys, index, vals, n, width, num_keys)
    _close(got, want, vals, 4 * max(np.bincount(keys).max(), 1))
    assert not np.any(got[int(keys.max()) + 1:])


def _placed_runs(seed, n, runs):
    """Sorted keys [n]: the given runs ``(start, length)`` exactly there (each a key of its own),
    the other elements in short runs of 1-69, and some keys without elements."""
    rng = np.random.default_rng(seed)
    keys = np.empty(n, np.int64)
    key, pos = 0, 0
    for start, length in sorted(runs) + [(n, 0)]:
        while pos < start:
            step = min(int(rng.integers(1, 70)), start - pos)
            keys[pos:pos + step] = key
            pos += step
            key += 1 + int(rng.random() < 0.1)      # some keys have no elements
        if length:
            keys[start:start + length] = key
            pos, key = start + length, key + 1 + int(rng.random() < 0.1)
    for start, length in runs:                       # each placed run is one whole key's run
        assert np.all(keys[start:start + length] == keys[start])
        assert start == 0 or keys[start - 1] != keys[start]
        assert start + length == n or keys[start + length] != keys[start]
    return keys.astype(np.uint32)


def _gather_against_segment_sum(ctx, keys, seed):
    """SegmentGather and SegmentSum over the same elements; returns (gather, segment sum, spans,
    index, vals, plain float64 per-key sums)."""
    n = len(keys)
    rng = np.random.default_rng(seed)
    index = rng.permutation(n).astype(np.uint32)
    vals = rng.normal(size=(n, 2, 4)).astype(np.float32)
    num_keys = int(keys.max()) + 3
    spans = key_spans(keys, num_keys)
    bufs = {name: ctx.upload(a, name) for a, name in ((keys, "keys"), (index, "index"), (vals, "vals"),
                                                      (spans, "spans"))}
    ss = SegmentSum(ctx, Scratch(ctx), "test_gather_sum")
    want_out = ctx.buffer(32 * num_keys, "want")
    _run(ctx, lambda enc: ss.record(enc, bufs["keys"], bufs["index"], bufs["vals"], n, 2, want_out))
    got_out = ctx.upload(np.full((num_keys, 2, 4), np.nan, np.float32), "got")   # overwritten, not added to
    _run(ctx, lambda enc: SegmentGather(ctx)(enc, bufs["spans"], bufs["index"], bufs["vals"], got_out, num_keys, n))
    got = ctx.read(got_out, np.float32, 8 * num_keys).reshape(num_keys, 2, 4)
    want = ctx.read(want_out, np.float32, 8 * num_keys).reshape(num_keys, 2, 4)
    plain = np.zeros((num_keys, 2, 4))
    np.add.at(plain, keys, vals[index].astype(np.float64))
    return got, want, spans, index, vals, plain


C2 = CHUNK * CHUNK


@pytest.mark.parametrize("n,runs", [
    (1, []),
    (CHUNK, [(0, CHUNK)]),                                         # the whole array, one level
    (3 * CHUNK + 5, [(11, CHUNK + 3)]),                            # across a chunk boundary
    (C2 + 300, [(30, 700), (C2, 129), (C2 + 140, 160)]),           # at a chunk of chunks; at the end
    (3 * C2 + 100, [(0, 3 * C2 + 100)]),                           # the whole array: 4 top-level elements
    (2 * C2 + 777, [(0, 5000), (5000, 2 * C2 + 777 - 5000)]),      # from the start; to the end
    (CHUNK ** 3 + 5000, [(29, 3 * C2 + 17), (10 * C2, 9000), (30 * C2 + 63, C2 + 1)]),   # three levels
])
def test_segment_gather(ctx, n, runs):
    """One invocation per key over its own run gives SegmentSum's sums bit for bit: runs inside
    a chunk, across chunks, from and to chunks of chunks, the whole array, over two and three
    levels of the up-sweep; keys without elements get zero (``out`` is written, not added to);
    within float32 rounding of the float64 per-key sum; the float32 twin the same bits."""
    assert SegmentGather(ctx).chunk == CHUNK                      # the kernel's CHUNK is segment.wgsl's
    keys = _placed_runs(n, n, runs)
    assert segment_levels(n, CHUNK) == twin._levels(n)
    got, want, spans, index, vals, plain = _gather_against_segment_sum(ctx, keys, n + 1)
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(got, twin.segment_gather(spans, index, vals, n, np.float32))
    np.testing.assert_allclose(twin.segment_gather(spans, index, vals, n), plain, rtol=0, atol=1e-9)
    _close(got, plain, vals, int(np.bincount(keys).max()))
    if n > C2:                                                    # a plain in-order sum would differ here
        sequential = np.zeros_like(got)
        for k in range(len(spans)):
            for e in range(*spans[k]):
                sequential[k] = sequential[k] + vals[index[e]]
        assert not np.array_equal(got, sequential)


def test_segment_gather_longest_runs(ctx):
    """Eight neighbouring keys of nearly MAX_RUN elements each (the loop budget's worst case: the
    lanes of one SIMD vector loop in step), three levels up: SegmentSum's bits, and fits()."""
    top_n = CHUNK ** 3 + 40_000
    runs, start = [], 37
    for i in range(8):
        length = SegmentGather.MAX_RUN - 7 * i
        runs.append((start, length))
        start += length
    keys = _placed_runs(5, top_n, runs)
    assert segment_levels(top_n, CHUNK) == 3
    assert SegmentGather(ctx).fits(top_n, int(np.bincount(keys).max()))
    got, want, _, _, vals, plain = _gather_against_segment_sum(ctx, keys, 6)
    np.testing.assert_array_equal(got, want)
    _close(got, plain, vals, SegmentGather.MAX_RUN)


def test_segment_gather_in_ranges(ctx, monkeypatch):
    """Spans and sums larger than one binding (forced small): the keys in ranges, each range's
    spans and sums bound from its first key; the same bits as one range."""
    import tsplus_wgpu.gpu.chunks as chunks
    n = 20000
    keys = _placed_runs(3, n, [(1000, 300)])
    num_keys = int(keys.max()) + 1
    rng = np.random.default_rng(4)
    index = rng.permutation(n).astype(np.uint32)
    vals = rng.normal(size=(n, 2, 4)).astype(np.float32)
    spans = key_spans(keys, num_keys)
    bufs = [ctx.upload(a, name) for a, name in ((spans, "spans"), (index, "index"), (vals, "vals"))]
    monkeypatch.setattr(chunks, "CHUNK_BYTES", 2**12)
    assert 32 * num_keys > 3 * 2**12
    out = ctx.buffer(32 * num_keys, "out")
    _run(ctx, lambda enc: SegmentGather(ctx)(enc, *bufs, out, num_keys, n))
    got = ctx.read(out, np.float32, 8 * num_keys).reshape(num_keys, 2, 4)
    np.testing.assert_array_equal(got, twin.segment_gather(spans, index, vals, n, np.float32))


def test_segment_gather_fits():
    """Runs past MAX_RUN (lavapipe's loop budget) or values past one binding take SegmentSum."""
    class _Ctx:
        limits = {"max-storage-buffer-binding-size": 2**27, "max-buffer-size": 2**28}
    g = SegmentGather.__new__(SegmentGather)
    g.ctx, g.chunk = _Ctx(), CHUNK
    assert g.fits(3_000_000, SegmentGather.MAX_RUN)
    assert not g.fits(3_000_000, SegmentGather.MAX_RUN + 1)
    assert not g.fits(2**27 // 32 + 1, 10)
