"""Float64 twins of ``shaders/reduce/``: ``max_reduce`` and the deterministic segmented sum
(``segment_up``, ``segment_down``, and ``segment_sum``, the two composed level by level as
:class:`~tsplus_wgpu.kernels.reduce.SegmentSum` does), and ``segment_gather``, the same sums
per key in the same order. Values are ``vec4`` lanes: an
element's value is ``[width, 4]``. ``dtype=np.float32`` adds in float32, in the kernels'
order (their sums are plain float additions, so that reproduces them bit for bit)."""

from __future__ import annotations

import numpy as np

from ..gpu.wgsl import constant

#: Elements per chunk and level (``CHUNK`` of ``shaders/common/segment.wgsl``).
CHUNK = constant("CHUNK", "segment")


def max_reduce(values, n):
    """``result[0]``: the largest of ``values[:n]`` (u32), 0 when ``n`` is 0."""
    v = np.asarray(values, np.uint32)[:int(n)]
    return np.uint32(v.max()) if v.size else np.uint32(0)


def _element_values(vals_in, index, width, gather, dtype):
    """A function: element i -> its value ``[width, 4]`` (through ``index`` on level 0)."""
    vals = np.asarray(vals_in).reshape(-1, width, 4).astype(dtype)
    index = np.asarray(index, np.int64)
    return (lambda i: vals[index[i]]) if gather else (lambda i: vals[i])


def _run_sum(keys, value, lo, hi, width, dtype):
    """Sum of the run of ``keys[lo]`` from ``lo`` up to ``hi`` (exclusive), in order."""
    key = keys[lo]
    s = np.zeros((width, 4), dtype)
    for e in range(lo, hi):
        if keys[e] != key:
            break
        s = s + value(e)
    return s


def segment_up(keys_in, index, vals_in, n, width, gather, dtype=np.float64):
    """One up-sweep level: per chunk of ``CHUNK`` elements, its first key and the sum of its
    leading run. Returns ``(keys_out [ceil(n / CHUNK)] u32, vals_out [ceil(n / CHUNK), width, 4])``."""
    keys = np.asarray(keys_in, np.uint32)
    n = int(n)
    nc = (n + CHUNK - 1) // CHUNK
    keys_out = np.zeros(nc, np.uint32)
    vals_out = np.zeros((nc, width, 4), dtype)
    value = _element_values(vals_in, index, width, gather, dtype)
    for c in range(nc):
        first = c * CHUNK
        keys_out[c] = keys[first]
        vals_out[c] = _run_sum(keys, value, first, min(first + CHUNK, n), width, dtype)
    return keys_out, vals_out


def segment_down(keys_in, index, vals_in, out, n, width, gather, top, dtype=np.float64):
    """One down-sweep level: ``out[key] = (the run's elements within its chunk) + out[key]``
    at every run start not at a chunk start (on the ``top`` level: every run start, the whole
    run). Returns the new ``out [keys, width, 4]``."""
    keys = np.asarray(keys_in, np.uint32)
    n = int(n)
    res = np.array(out, dtype).reshape(-1, width, 4)
    value = _element_values(vals_in, index, width, gather, dtype)
    for i in range(n):
        if i > 0 and keys[i - 1] == keys[i]:
            continue
        if top:
            end = n
        elif i % CHUNK == 0:
            continue
        else:
            end = min(n, (i // CHUNK + 1) * CHUNK)
        k = keys[i]
        res[k] = _run_sum(keys, value, i, end, width, dtype) + res[k]
    return res


def segment_sum(keys, index, vals, n, width, num_keys, dtype=np.float64):
    """``out [num_keys, width, 4]``: per key the sum of its elements' values (``vals`` read
    through ``index``), computed level by level as ``SegmentSum.record``: up-sweeps while a
    level has more than ``CHUNK`` elements, then down-sweeps from the coarsest level."""
    out = np.zeros((num_keys, width, 4), dtype)
    n = int(n)
    if n == 0:
        return out
    levels = [(np.asarray(keys, np.uint32)[:n], np.asarray(vals, dtype), n)]
    while levels[-1][2] > CHUNK:
        k_in, v_in, n_l = levels[-1]
        k_out, v_out = segment_up(k_in, index, v_in, n_l, width, len(levels) == 1, dtype)
        levels.append((k_out, v_out, k_out.size))
    for depth in range(len(levels) - 1, -1, -1):
        k_in, v_in, n_l = levels[depth]
        out = segment_down(k_in, index, v_in, out, n_l, width, depth == 0, depth == len(levels) - 1, dtype)
    return out


def _levels(n):
    """The coarsest level of the segmented sum over ``n`` elements."""
    top = 0
    while n > CHUNK:
        n = -(-n // CHUNK)
        top += 1
    return top


def segment_gather(spans, index, vals, n, dtype=np.float64):
    """``out [keys, 2, 4]``: per key the sum of the values of its run ``spans[key] = [a, b)`` of
    the ``n`` sorted elements (``vals [*, 2, 4]`` read through ``index``), added as
    :func:`segment_sum` adds them (so in float32 the same bits): on level l the run is
    ``[a_l, b_l)`` (``a_{l+1} = ceil(a_l / CHUNK)``, the same for b), level l + 1's element c the
    in-order sum of level l's ``[c CHUNK, min((c + 1) CHUNK, b_l))``; from the coarsest level
    down, ``total = head + total`` where the run does not start at a chunk start (head: up to the
    chunk's end), and the whole run on the top level."""
    spans = np.asarray(spans, np.int64).reshape(-1, 2)
    vals = np.asarray(vals).reshape(-1, 2, 4).astype(dtype)
    index = np.asarray(index, np.int64)
    top = _levels(int(n))
    out = np.zeros((len(spans), 2, 4), dtype)

    def element(level, c, b0):
        if level == 0:
            return vals[index[c]]
        end = b0
        for _ in range(level - 1):
            end = -(-end // CHUNK)
        s = np.zeros((2, 4), dtype)
        for i in range(c * CHUNK, min(c * CHUNK + CHUNK, end)):
            s = s + element(level - 1, i, b0)
        return s

    for key, (a0, b0) in enumerate(spans):
        total = np.zeros((2, 4), dtype)
        for level in range(top, -1, -1):
            al, bl = a0, b0
            for _ in range(level):
                al, bl = -(-al // CHUNK), -(-bl // CHUNK)
            if al >= bl or (level < top and al % CHUNK == 0):
                continue
            hi = bl if level == top else min(bl, (al // CHUNK + 1) * CHUNK)
            s = np.zeros((2, 4), dtype)
            for c in range(al, hi):
                s = s + element(level, c, b0)
            total = s + total
        out[key] = total
    return out


__all__ = ["CHUNK", "max_reduce", "segment_up", "segment_down", "segment_sum", "segment_gather"]
