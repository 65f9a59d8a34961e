"""shaders/sort/: each kernel alone against its twin (exactly: integer stages), then the
composed prefix sum and radix sort against NumPy."""

import numpy as np
import pytest

from tsplus_wgpu.gpu.stage import Scratch
from tsplus_wgpu.kernels.sort import RadixCount, RadixScatter, RadixSort, ScanAdd, ScanBlock, scan_numpy
from tsplus_wgpu.reference import sort as twin
from scenes import submit as run


def random_u32(rng, n, high=2**32):
    return rng.integers(0, high, n, dtype=np.uint64).astype(np.uint32)


@pytest.fixture(params=[None, 3], ids=["grid-1d", "grid-2d"])
def max_dim(request, ctx, monkeypatch):
    """Also run with at most 3 workgroups per dimension: the 2-D grid that more than 65535
    workgroups take (and its overshoot workgroups), at a size lavapipe runs quickly."""
    if request.param is not None:
        monkeypatch.setitem(ctx.limits, "max-compute-workgroups-per-dimension", request.param)
    return request.param


def test_constants_come_from_the_wgsl(ctx):
    assert ScanBlock(ctx).const("SCAN_BLOCK") == twin.SCAN_BLOCK == 1024
    count = RadixCount(ctx)
    assert count.const("SORT_BLOCK") == twin.SORT_BLOCK == count.invocations * count.const("SORT_ITEMS")
    assert 2 ** count.const("RADIX_BITS") == count.const("RADIX") == twin.RADIX


@pytest.mark.parametrize("n", [1, 5, 1023, 1024, 1025, 7 * 1024 + 3, 300_001])
def test_scan_block(ctx, max_dim, n):
    rng = np.random.default_rng(n)
    data = random_u32(rng, n + 7)            # past n: left alone; full range: sums wrap modulo 2^32
    nb = -(-n // twin.SCAN_BLOCK)
    buf = ctx.upload(data)
    sums = ctx.buffer(4 * (nb + 8))          # room for the 2-D grid's overshoot workgroups
    run(ctx, lambda enc: ScanBlock(ctx)(enc, buf, sums, n))
    ref, ref_sums = twin.scan_block(data, n)
    np.testing.assert_array_equal(ctx.read(buf, np.uint32, n + 7), ref)
    np.testing.assert_array_equal(ctx.read(sums, np.uint32, nb), ref_sums)


@pytest.mark.parametrize("n", [1, 1023, 1025, 5 * 1024, 300_001])
def test_scan_add(ctx, max_dim, n):
    rng = np.random.default_rng(n)
    data = random_u32(rng, n + 5)
    offsets = random_u32(rng, -(-n // twin.SCAN_BLOCK))
    buf = ctx.upload(data)
    run(ctx, lambda enc: ScanAdd(ctx)(enc, buf, ctx.upload(offsets), n))
    np.testing.assert_array_equal(ctx.read(buf, np.uint32, n + 5), twin.scan_add(data, offsets, n))


def _sort_params(stage, n, shift):
    nb = -(-n // twin.SORT_BLOCK)
    return stage.uniform("SortParams", n=n, shift=shift, num_blocks=nb), nb


@pytest.mark.parametrize("n", [1, 3, 2047, 2048, 2049, 9 * 2048 + 5, 100_003])
@pytest.mark.parametrize("shift", [0, 4, 28])
def test_radix_count(ctx, max_dim, n, shift):
    rng = np.random.default_rng(n + shift)
    keys = random_u32(rng, n)
    keys[: n // 3] = keys[0]                 # a run of equal digits
    stage = RadixCount(ctx)
    sp, nb = _sort_params(stage, n, shift)
    counts = ctx.buffer(4 * twin.RADIX * nb)
    run(ctx, lambda enc: stage(enc, sp, ctx.upload(keys), counts, nb))
    ref = twin.radix_count(keys, n, shift, nb)
    np.testing.assert_array_equal(ctx.read(counts, np.uint32, twin.RADIX * nb), ref)
    assert int(ref.sum()) == n


@pytest.mark.parametrize("n", [1, 3, 2047, 2049, 9 * 2048 + 5, 100_003])
@pytest.mark.parametrize("shift", [0, 12, 28])
def test_radix_scatter(ctx, max_dim, n, shift):
    rng = np.random.default_rng(n + shift)
    keys = random_u32(rng, n)
    keys[n // 2:] = random_u32(rng, n - n // 2, 4) << np.uint32(shift)   # few distinct digits: stability
    vals = rng.permutation(n).astype(np.uint32)
    stage = RadixScatter(ctx)
    sp, nb = _sort_params(stage, n, shift)
    offsets, total = twin.prefix_sum(twin.radix_count(keys, n, shift, nb))
    assert total == n
    k_out, v_out = ctx.buffer(4 * n), ctx.buffer(4 * n)
    run(ctx, lambda enc: stage(enc, sp, ctx.upload(keys), ctx.upload(vals), ctx.upload(offsets), k_out, v_out, nb))
    ref_k, ref_v = twin.radix_scatter(keys, vals, offsets, n, shift, nb)
    np.testing.assert_array_equal(ctx.read(k_out, np.uint32, n), ref_k)
    np.testing.assert_array_equal(ctx.read(v_out, np.uint32, n), ref_v)
    # one pass sorts by that digit, stably
    order = np.argsort((keys >> np.uint32(shift)) & np.uint32(twin.RADIX - 1), kind="stable")
    np.testing.assert_array_equal(ref_v, vals[order])


# ---- the composed sort and scan (moved from tests/test_sort_scan.py) -------------------------

@pytest.fixture(scope="module")
def sorter(ctx):
    return RadixSort(ctx, Scratch(ctx), "test_sort")


@pytest.mark.parametrize("n", [0, 1, 2, 2047, 2048, 2049, 100_003, 2**20 + 3])
def test_sort_random_matches_stable_argsort(sorter, n):
    rng = np.random.default_rng(n)
    keys = rng.integers(0, 2**32, n, dtype=np.uint64).astype(np.uint32)
    ks, vs = sorter.sort(keys)
    ref = np.argsort(keys, kind="stable")
    np.testing.assert_array_equal(vs, ref)
    np.testing.assert_array_equal(ks, keys[ref])


@pytest.mark.parametrize("key", [0, 7, 0xFFFFFFFF])
def test_sort_all_equal_keys_keeps_input_order(sorter, key):
    keys = np.full(10_007, key, np.uint32)
    vals = np.random.default_rng(0).permutation(10_007).astype(np.uint32)
    ks, vs = sorter.sort(keys, vals)
    np.testing.assert_array_equal(vs, vals)
    np.testing.assert_array_equal(ks, keys)


def test_sort_maximum_keys_and_few_distinct(sorter):
    rng = np.random.default_rng(3)
    keys = rng.choice(np.array([0, 1, 0x7FFFFFFF, 0x80000000, 0xFFFFFFFE, 0xFFFFFFFF], np.uint32), 50_000)
    ks, vs = sorter.sort(keys)
    np.testing.assert_array_equal(vs, np.argsort(keys, kind="stable"))


@pytest.mark.parametrize("bits", [1, 4, 11, 13])
def test_sort_low_bits_only(sorter, bits):
    rng = np.random.default_rng(bits)
    keys = rng.integers(0, 2**bits, 30_000).astype(np.uint32)
    ks, vs = sorter.sort(keys, bits=bits)
    np.testing.assert_array_equal(vs, np.argsort(keys, kind="stable"))


@pytest.mark.parametrize("bits", [4, 13, 32])
def test_radix_sort_twin_matches_stable_argsort(bits):
    rng = np.random.default_rng(bits)
    keys = random_u32(rng, 20_011, 2**bits)
    ks, vs = twin.radix_sort(keys, np.arange(20_011, dtype=np.uint32), bits)
    np.testing.assert_array_equal(vs, np.argsort(keys, kind="stable"))
    np.testing.assert_array_equal(ks, np.sort(keys))


@pytest.mark.parametrize("n", [0, 1, 1023, 1024, 1025, 1024 * 1024 + 1, 3_000_001])
def test_prefix_sum_exact(ctx, n):
    rng = np.random.default_rng(n)
    v = rng.integers(0, 1000, n).astype(np.uint32)
    out, total = scan_numpy(ctx, v)
    ref = np.concatenate([[0], np.cumsum(v, dtype=np.uint64)[:-1]]).astype(np.uint32) if n else v
    np.testing.assert_array_equal(out, ref)
    assert total == int(v.sum(dtype=np.uint64))
    if n:
        tw, tw_total = twin.prefix_sum(v)
        np.testing.assert_array_equal(tw, ref)
        assert tw_total == total
