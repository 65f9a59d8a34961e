"""Per-item arrays larger than one storage binding, bound a range of items at a time.

A kernel that reads and writes only item ``i`` of each of its per-item arrays (a vertex's SH,
its gradient, an Adam element) can run over ``n`` items in chunks: each dispatch binds the same
item range ``[start, start + count)`` of every array (:class:`Slice`, a sub-range binding) and
sees it from index 0. :func:`item_chunks` picks the ranges: every slice fits the device's
storage-binding limit and starts at a multiple of the device's offset alignment (256 bytes in
WebGPU). One chunk (everything fits) binds the whole buffers, as a plain dispatch does.

The buffer itself may then be larger than one binding, up to the device's buffer-size limit
(``GpuContext.buffer(..., chunked=True)``). docs/memory.md lists which arrays are bound so.
"""

from __future__ import annotations

import math
from typing import NamedTuple


class Slice(NamedTuple):
    """``size`` bytes of ``buffer`` from byte ``offset``, bound as one storage binding."""

    buffer: object
    offset: int
    size: int


def _limits(ctx_or_limits):
    return getattr(ctx_or_limits, "limits", ctx_or_limits)


#: tests: bind chunked arrays at most this many bytes at a time (None: the device's limit), so
#: the chunked paths run on small models
CHUNK_BYTES = None


def binding_bytes(ctx_or_limits):
    """The most bytes one storage binding of a chunked array may hold on this device."""
    lim = _limits(ctx_or_limits)
    cap = min(int(lim["max-storage-buffer-binding-size"]), int(lim["max-buffer-size"]))
    return cap if CHUNK_BYTES is None else min(cap, int(CHUNK_BYTES))


def item_chunks(ctx_or_limits, n, widths, multiple=1):
    """``[(start, count)]`` covering items ``[0, n)``: ``widths`` are the bytes per item of every
    array bound per item (each slice ``count * width`` bytes fits one binding; each ``start *
    width`` is a multiple of the offset alignment). ``multiple``: every ``start`` is also a
    multiple of it (e.g. a whole vertex of flat SH elements). ``[(0, n)]`` when all fit."""
    lim = _limits(ctx_or_limits)
    n = int(n)
    widest = max(int(w) for w in widths)
    cap = binding_bytes(lim)
    if n * widest <= cap:
        return [(0, n)]
    align = int(lim.get("min-storage-buffer-offset-alignment", 256))
    step = int(multiple)
    for w in widths:
        step = math.lcm(step, align // math.gcd(align, int(w)))
    count = cap // widest // step * step
    if count <= 0:
        raise ValueError(f"one item of {widest} bytes in steps of {step} does not fit a "
                         f"{cap:,}-byte storage binding")
    return [(s, min(count, n - s)) for s in range(0, n, count)]


def item_slice(buffer, start, count, width):
    """The binding of items ``[start, start + count)`` of ``width`` bytes each in ``buffer``."""
    return Slice(buffer, int(start) * int(width), max(4, int(count) * int(width)))


#: the page ``(lo, hi)`` of an array that fits one binding: every item
ALL = (0, 0xFFFFFFFF)


def pages(ctx_or_limits, buffer, count, width):
    """``[(lo, hi, binding)]``: the first ``count`` items (``width`` bytes each) of ``buffer`` a
    binding's page at a time, for kernels that read such an array at any index and skip the
    items outside ``[lo, hi)``; one page ``(*ALL, buffer)`` where they fit one binding."""
    chunks = item_chunks(ctx_or_limits, count, [width])
    if len(chunks) == 1:
        return [(*ALL, buffer)]
    return [(s, s + c, item_slice(buffer, s, c, width)) for s, c in chunks]


def pair_windows(num_pairs, max_tile_pairs, capacity, what="backward pair statistics"):
    """Windows of whole tiles over a view's tile-sorted pairs, for per-pair data of which one
    binding holds ``capacity`` pairs (the backward's statistics, the projected triangles in
    pair order): ``[(lo, hi, length)]``.

    The tiles whose first pair is in ``[lo, hi)`` replay in a window; their statistics fill
    pairs ``[lo, lo + length)`` (a tile that starts before ``hi`` may end after it), at most
    ``capacity`` of them. One window ``(0, P, P)`` when all ``P`` pairs fit."""
    P, big, cap = int(num_pairs), int(max_tile_pairs), int(capacity)
    if P <= cap:
        return [(0, P, P)]
    step = cap - big
    if step < 1:
        raise ValueError(f"{what}: one 16x16 tile has {big:,} tile-triangle pairs, more than one "
                         f"storage binding holds ({cap:,}); use fewer triangles or a smaller image")
    out = []
    for lo in range(0, P, step):
        hi = min(lo + step, P)
        out.append((lo, hi, min(P, hi + big) - lo))
    return out


__all__ = ["pair_windows", "ALL", "CHUNK_BYTES", "Slice", "binding_bytes", "item_chunks", "item_slice", "pages"]
