"""Portable radix sort and prefix sum: exact against NumPy."""

import numpy as np
import pytest

from tsplus_wgpu.stages import RadixSort, Scratch, scan_numpy


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


@pytest.mark.parametrize("n", [0, 1, 1023, 1024, 1025, 1024 * 1024 + 1, 3_000_001])
def test_prefix_sum_exact(ctx, n):
    rng = np.random.default_rng(n)
    v = rng.integers(0, 1000, n).astype(np.uint32)
    out, total = scan_numpy(ctx, v)
    ref = np.concatenate([[0], np.cumsum(v, dtype=np.uint64)[:-1]]).astype(np.uint32) if n else v
    np.testing.assert_array_equal(out, ref)
    assert total == int(v.sum(dtype=np.uint64))
