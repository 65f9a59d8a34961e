"""Twins of shaders/sort/: :func:`scan_block`, :func:`scan_add` (the exclusive prefix sum,
composed in :func:`prefix_sum`), :func:`radix_count`, :func:`radix_scatter` (one pass of
the stable LSD radix sort, composed in :func:`radix_sort`), and :func:`depth_order`, the
drawing order the depth sort gives. Integer arithmetic wraps modulo 2^32 as WGSL's u32 does;
block sizes and bits per pass are the WGSL's (``shaders/common/scan.wgsl``, ``radix.wgsl``)."""

from __future__ import annotations

import numpy as np

from ..gpu.wgsl import constant

SCAN_BLOCK = constant("SCAN_BLOCK", "scan")
SORT_BLOCK = constant("SORT_BLOCK", "radix")
RADIX_BITS = constant("RADIX_BITS", "radix")
RADIX = constant("RADIX", "radix")
_U32 = np.uint64(0xFFFFFFFF)


def _blocks(n, per):
    return max(1, (int(n) + per - 1) // per)


def scan_block(data, n):
    """Twin of scan_block: ``(data [len(data)], block_sums [ceil(n / SCAN_BLOCK)])`` uint32: the
    first ``n`` values scanned (exclusive) within each block of ``SCAN_BLOCK``, the rest unchanged,
    and each block's total."""
    out = np.array(data, np.uint32)
    nb = _blocks(n, SCAN_BLOCK)
    v = np.zeros(nb * SCAN_BLOCK, np.uint64)
    v[:n] = out[:n]
    incl = np.cumsum(v.reshape(nb, SCAN_BLOCK), axis=1)              # [nb, SCAN_BLOCK], exact in 64 bits
    out[:n] = ((incl - v.reshape(nb, SCAN_BLOCK)).ravel()[:n] & _U32).astype(np.uint32)
    return out, (incl[:, -1] & _U32).astype(np.uint32)


def scan_add(data, block_offsets, n):
    """Twin of scan_add: ``data [len(data)]`` uint32 with ``block_offsets[i // SCAN_BLOCK]`` added
    to each of the first ``n`` values."""
    out = np.array(data, np.uint32)
    add = np.asarray(block_offsets, np.uint64)[np.arange(n) // SCAN_BLOCK]
    out[:n] = ((out[:n].astype(np.uint64) + add) & _U32).astype(np.uint32)
    return out


def prefix_sum(values):
    """The exclusive prefix sum as ``PrefixSum`` composes it: ``(scan [n] uint32, total)``."""
    values = np.asarray(values, np.uint32)
    n = values.shape[0]
    out, sums = scan_block(values, n)
    if sums.shape[0] == 1:
        return out, int(sums[0])
    offsets, total = prefix_sum(sums)
    return scan_add(out, offsets, n), total


def _digits(keys, n, shift, num_blocks):
    """Digit and block of each of the first n keys that a dispatched block reads."""
    keys = np.asarray(keys, np.uint32)[:n]
    block = np.arange(n) // SORT_BLOCK
    inside = block < num_blocks
    d = (keys >> np.uint32(int(shift) & 31)) & np.uint32(RADIX - 1)
    return keys, d.astype(np.int64), block, inside


def radix_count(keys, n, shift, num_blocks):
    """Twin of radix_count: ``counts [RADIX * num_blocks]`` uint32, digit-major
    (``counts[digit * num_blocks + block]``), of digit ``(key >> shift) % RADIX`` per block of ``SORT_BLOCK``."""
    _, d, block, inside = _digits(keys, n, shift, num_blocks)
    return np.bincount(d[inside] * num_blocks + block[inside], minlength=RADIX * num_blocks).astype(np.uint32)


def radix_scatter(keys, vals, offsets, n, shift, num_blocks):
    """Twin of radix_scatter: ``(keys_out [n], vals_out [n])`` uint32. Key i of block b with digit d
    goes to ``offsets[d * num_blocks + b]`` + the keys of digit d before it in block b (stable)."""
    keys, d, block, inside = _digits(keys, n, shift, num_blocks)
    vals = np.asarray(vals, np.uint32)[:n]
    group = block * RADIX + d                                        # [n] (block, digit)
    idx = np.argsort(group, kind="stable")
    sorted_group = group[idx]
    rank = np.empty(n, np.int64)
    rank[idx] = np.arange(n) - np.searchsorted(sorted_group, sorted_group, side="left")
    dst = np.asarray(offsets, np.int64)[d * num_blocks + np.minimum(block, num_blocks - 1)] + rank
    keys_out = np.zeros(n, np.uint32)
    vals_out = np.zeros(n, np.uint32)
    keys_out[dst[inside]] = keys[inside]
    vals_out[dst[inside]] = vals[inside]
    return keys_out, vals_out


def radix_sort(keys, vals, bits=32):
    """The stable LSD radix sort as ``RadixSort`` composes it (low ``bits`` bits of the keys):
    per pass radix_count, the exclusive prefix sum of the counts, radix_scatter."""
    keys = np.asarray(keys, np.uint32)
    vals = np.asarray(vals, np.uint32)
    n = keys.shape[0]
    passes = (int(bits) + RADIX_BITS - 1) // RADIX_BITS
    if n <= 1:
        return keys.copy(), vals.copy()
    nb = _blocks(n, SORT_BLOCK)
    for p in range(passes):
        offsets, _ = prefix_sum(radix_count(keys, n, RADIX_BITS * p, nb))
        keys, vals = radix_scatter(keys, vals, offsets, n, RADIX_BITS * p, nb)
    return keys, vals


def depth_order(proj):
    """Drawing order (the depth sort of project_triangles' keys): visible triangles by
    centroid depth, ties in index order. ``proj``: a :class:`~.project.Projection`."""
    key = np.where(proj.visible, proj.depth, np.inf)
    return np.argsort(key, kind="stable")
