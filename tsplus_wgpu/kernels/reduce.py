"""Host classes of shaders/reduce/: the max reduction (``max_reduce``) and the deterministic
segmented sum (``segment_up``, ``segment_down``; composed by :class:`SegmentSum`), and
``segment_gather`` (:class:`SegmentGather`): the same sums per key, bit for bit, for keys
whose runs are known (sorted once, reused)."""

from __future__ import annotations

import numpy as np

from ..gpu import Stage
from ..gpu.chunks import ALL, binding_bytes, pages


class MaxReduce(Stage):
    """The largest of ``n`` u32 values into ``result[0]`` (one workgroup)."""

    stage = "max_reduce"

    def __call__(self, enc, values, result, n, profiler=None, label=None):
        rp = self.uniform("ReduceParams", n=n)
        self.dispatch(enc, 1, dict(rp=rp, values=values, result=result), profiler, label)


class SegmentUp(Stage):
    """One level of the up-sweep: per chunk of ``CHUNK`` elements its leading run's sum and key."""

    stage = "segment_up"

    def __call__(self, enc, keys_in, index, vals_in, keys_out, vals_out, n, width, gather, profiler=None,
                 label=None, vals_range=ALL):
        """``vals_range``: the values ``vals_in`` holds (of the gather at level 0; the others count 0)."""
        sp = self.uniform("SegParams", n=n, width=width, gather=int(gather), top=0, val_lo=vals_range[0],
                          val_hi=vals_range[1], key_lo=0, key_hi=0xFFFFFFFF)
        chunks = self.groups(n, self.const("CHUNK"))
        self.dispatch(enc, self.groups(chunks), dict(sp=sp, keys_in=keys_in, index=index, vals_in=vals_in,
                                                     keys_out=keys_out, vals_out=vals_out), profiler, label)


class SegmentDown(Stage):
    """One level of the down-sweep: every run start adds its run (within its chunk, or the
    whole run on the ``top`` level) to ``out[key]``."""

    stage = "segment_down"

    def __call__(self, enc, keys_in, index, vals_in, out, n, width, gather, top, profiler=None, label=None,
                 vals_range=ALL, keys_range=ALL):
        """``vals_range`` as in :class:`SegmentUp`; ``keys_range``: the keys ``out`` holds (others
        are not written)."""
        sp = self.uniform("SegParams", n=n, width=width, gather=int(gather), top=int(top), val_lo=vals_range[0],
                          val_hi=vals_range[1], key_lo=keys_range[0], key_hi=keys_range[1])
        self.dispatch(enc, self.groups(n), dict(sp=sp, keys_in=keys_in, index=index, vals_in=vals_in, out=out),
                      profiler, label)


class SegmentSum:
    """Deterministic segmented sum with bounded work per invocation (see
    ``shaders/common/segment.wgsl``): ``out[key] = sum of the values of the elements with
    that key``, in a fixed order, for sorted ``keys [n]``; element i's value is the
    ``width`` vec4s at ``vals[index[i] * width:]``. ``out`` (``[keys, width]`` vec4) is
    zeroed first, so keys without elements get zero; with ``clear=False`` the sums are added
    to what ``out`` holds (``out[key] += ...``, the sum of several batches of elements).

    ``vals`` and ``out`` may be larger than one storage binding (``gpu/chunks.py``): then the
    sum runs once per page of gathered values (each adding its values' share) and writes each
    page of keys through its own binding; the order of the additions then differs from the
    one-binding sum's (a sum of per-page sums)."""

    def __init__(self, ctx, scratch, name):
        self.ctx = ctx
        self.scratch = scratch
        self.name = name
        self.up = SegmentUp(ctx)
        self.down = SegmentDown(ctx)
        self.chunk = self.up.const("CHUNK")    # elements per chunk and level

    def _pages(self, buf, width, count):
        """``[(range, binding)]`` of the first ``count`` items of a ``[*, width]`` vec4 buffer: one
        of all where it fits a binding (a scratch buffer may hold more than is used)."""
        item = 16 * width
        return [((lo, hi), page) for lo, hi, page in pages(self.ctx, buf, min(int(count), buf.size // item), item)]

    def record(self, enc, keys, index, vals, n, width, out, profiler=None, label=None, clear=True, num_keys=None):
        """``n`` elements; their values are ``vals[index[i]]`` with ``index`` a permutation of
        ``0 .. n-1`` (so ``n`` values); ``num_keys``: the keys ``out`` holds (default: as many as
        it has room for), which sizes its pages where it outgrows a binding."""
        assert width in (1, 2, 5)
        if clear:
            enc.clear_buffer(out)
        if n == 0:
            return
        outs = self._pages(out, width, out.size // (16 * width) if num_keys is None else num_keys)
        for vals_range, vals_page in self._pages(vals, width, n):
            levels = [(keys, vals_page, int(n))]
            while levels[-1][2] > self.chunk:
                k_in, v_in, n_l = levels[-1]
                nc = (n_l + self.chunk - 1) // self.chunk
                depth = len(levels)
                k_out = self.scratch.get(f"{self.name}_keys_{depth}", 4 * nc)
                v_out = self.scratch.get(f"{self.name}_vals_{depth}", 16 * width * nc)
                self.up(enc, k_in, index, v_in, k_out, v_out, n_l, width, depth == 1, profiler, label, vals_range)
                levels.append((k_out, v_out, nc))
            for keys_range, out_page in outs:
                for depth in range(len(levels) - 1, -1, -1):
                    k_in, v_in, n_l = levels[depth]
                    self.down(enc, k_in, index, v_in, out_page, n_l, width, depth == 0, depth == len(levels) - 1,
                              profiler, label, vals_range, keys_range)


def segment_levels(n, chunk):
    """The coarsest level of :class:`SegmentSum` over ``n`` elements (its up-sweeps)."""
    top, n = 0, int(n)
    while n > chunk:
        n = (n + chunk - 1) // chunk
        top += 1
    return top


def key_spans(keys, num_keys):
    """``[num_keys, 2]`` u32: each key's run ``[a, b)`` in the elements sorted by key (host;
    ``keys`` sorted or not: only their counts matter), as :class:`SegmentGather` reads them."""
    counts = np.bincount(np.asarray(keys, np.int64).reshape(-1), minlength=int(num_keys))[:int(num_keys)]
    ends = np.cumsum(counts)
    return np.stack([ends - counts, ends], axis=1).astype(np.uint32)


class SegmentGather(Stage):
    """:class:`SegmentSum`'s result for elements of two vec4s, with its additions in its order
    (the same bits where SegmentSum fits one binding), one invocation per key over the key's own
    run ``spans[key] = [a, b)`` of the ``n`` sorted elements (:func:`key_spans`); element i's
    value is ``vals[index[i] * 2:]``. ``out [keys, 2]`` vec4 is written, not added to. For
    runs of at most :attr:`MAX_RUN` elements (lavapipe's loop budget) and ``vals`` within one
    binding (:meth:`fits`); else take :class:`SegmentSum`."""

    stage = "segment_gather"
    #: the longest run one invocation sums. llvmpipe ends a shader call after 65535 loop
    #: iterations, counted per SIMD vector (8 invocations with AVX2): the level loops run in
    #: step across the lanes, so 8 neighbouring keys of this many elements take up to about
    #: 37,000 (simulated; top level 3, the most one 128 MiB binding of values allows)
    MAX_RUN = 16384

    def __init__(self, ctx, constants=None):
        super().__init__(ctx, constants)
        self.chunk = self.const("CHUNK")

    def fits(self, n, longest_run):
        """Whether ``n`` elements (their values bound whole) with runs of at most ``longest_run`` fit."""
        return (int(longest_run) <= self.MAX_RUN and 32 * int(n) <= binding_bytes(self.ctx)
                and segment_levels(n, self.chunk) <= 4)

    def __call__(self, enc, spans, index, vals, out, num_keys, n, profiler=None, label=None):
        """``num_keys`` keys (in ranges of keys where ``spans`` or ``out`` outgrow a binding), ``n`` elements."""
        if num_keys == 0:
            return
        top = segment_levels(n, self.chunk)
        self.dispatch_ranges(enc, num_keys, dict(spans=(spans, 8), out=(out, 32)), dict(index=index, vals=vals),
                             lambda s, c: dict(gp=self.uniform("GatherParams", count=c, top=top)), profiler, label)


__all__ = ["MaxReduce", "SegmentUp", "SegmentDown", "SegmentSum", "SegmentGather", "key_spans", "segment_levels"]
