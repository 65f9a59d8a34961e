"""Stage: the host side of one WGSL kernel (its pipeline, buffers bound by name, dispatch),
the 2-D dispatch grid and Scratch, named device buffers reused between calls."""

from __future__ import annotations

import numpy as np

from .chunks import Slice, item_chunks, item_slice
from .context import GpuContext


def grid(groups, max_dim=65535):
    """Split a 1-D workgroup count into a 2-D grid within the per-dimension limit."""
    groups = max(1, int(groups))
    if groups <= max_dim:
        return (groups, 1, 1)
    y = (groups + max_dim - 1) // max_dim
    x = (groups + y - 1) // y
    return (x, y, 1)


class Stage:
    """Owns the pipeline of one ``shaders/<stage>.wgsl`` and dispatches it with buffers
    bound by name. Subclasses set ``stage`` and give ``__call__`` a typed signature."""

    stage = ""

    def __init__(self, ctx: GpuContext, constants=None):
        self.ctx = ctx
        self.pipeline, self.layout, self.src = ctx.pipeline(self.stage, constants)
        self.workgroup_size = self.src.workgroup_size

    @property
    def invocations(self):
        """Invocations per workgroup of this kernel (from its ``@workgroup_size``)."""
        return self.src.invocations

    def const(self, name):
        """A scalar ``const`` of this kernel's WGSL (see :meth:`WgslSource.const`)."""
        return self.src.const(name)

    def groups(self, n, per=None):
        """Workgroups for ``n`` items, ``per`` items per workgroup (default: one per invocation)."""
        return groups(n, self.invocations if per is None else per)

    def uniform(self, struct_name, **values):
        dt = self.src.structs[struct_name]
        arr = np.zeros((), dt)
        for k, v in values.items():
            if k not in dt.names:
                raise KeyError(f"{self.stage}.wgsl: struct {struct_name} has no field {k}")
            arr[k] = v
        missing = [n for n in dt.names if n not in values and not n.startswith("_")]
        if missing:
            raise KeyError(f"{self.stage}.wgsl: struct {struct_name} fields not set: {missing}")
        return self.ctx.uniform(arr, label=f"{self.stage}.{struct_name}")

    def bind(self, buffers):
        """The bind group of ``buffers`` by binding name: a buffer (bound whole) or a
        :class:`~.chunks.Slice` (a byte range of one)."""
        want = set(self.src.bindings)
        got = set(buffers)
        if want != got:
            raise KeyError(f"{self.stage}.wgsl bindings: missing {sorted(want - got)}, unexpected {sorted(got - want)}")
        # a whole buffer larger than one binding (a chunked array's, or a scratch buffer grown by
        # a larger model) binds its first binding's worth: what one chunk of it uses
        lim = int(self.ctx.limits["max-storage-buffer-binding-size"]) // 4 * 4
        entries = []
        for name, b in buffers.items():
            buf, off, size = b if isinstance(b, Slice) else (b, 0, min(b.size, lim))
            entries.append((self.src.bindings[name].slot, buf, off, size))
        return self.ctx.bind_group(self.layout, entries)

    def dispatch(self, encoder, groups, buffers, profiler=None, label=None):
        """Record one dispatch; ``groups`` is an int (split into a 2-D grid) or an (x, y, z) tuple."""
        bg = self.bind(buffers)
        if isinstance(groups, int):
            groups = grid(groups, self.ctx.limits["max-compute-workgroups-per-dimension"])
        tw = profiler.writes(label or self.stage) if profiler is not None else None
        cp = encoder.begin_compute_pass(timestamp_writes=tw) if tw else encoder.begin_compute_pass()
        cp.set_pipeline(self.pipeline)
        cp.set_bind_group(0, bg)
        cp.dispatch_workgroups(*groups)
        cp.end()


    def dispatch_ranges(self, encoder, n, ranged, fixed, uniforms, profiler=None, label=None):
        """Dispatch over ``n`` items (one invocation each), a range of them at a time where an
        array of ``ranged`` ``{binding: (buffer, bytes per item)}`` outgrows one binding
        (:func:`~.chunks.item_chunks`; the kernel sees its range of each from index 0). ``fixed``
        ``{binding: buffer}`` is bound whole; ``uniforms(start, count)`` gives the range's
        uniform bindings. One range: every buffer bound whole, as :meth:`dispatch` does. ``label``:
        the profiler's name for it (default: the stage's)."""
        chunks = item_chunks(self.ctx, n, [w for _, w in ranged.values()])
        for start, count in chunks:
            bound = {k: b if len(chunks) == 1 else item_slice(b, start, count, w) for k, (b, w) in ranged.items()}
            self.dispatch(encoder, self.groups(count), dict(fixed, **uniforms(start, count), **bound), profiler, label)


class Scratch:
    """Named device buffers that grow on demand and are reused between calls."""

    def __init__(self, ctx: GpuContext):
        self.ctx = ctx
        self.buffers = {}

    def get(self, name, nbytes, grow=1.5, chunked=False):
        """Buffer ``name`` of at least ``nbytes``. One that is too small is dropped first (so
        the two never live at once, unless the caller still holds the old one) and made again
        ``grow`` times its old size where that is more than asked (fewer regrowths).
        ``chunked``: bound a range at a time, so it may exceed one binding (``GpuContext.buffer``)."""
        nbytes = max(16, int(nbytes))
        buf = self.buffers.get(name)
        if buf is None or buf.size < nbytes:
            old = 0 if buf is None else int(buf.size)
            self.buffers.pop(name, None)
            buf = None
            cap = max(nbytes, min(int(old * grow), self.ctx.limits["max-storage-buffer-binding-size"]))
            cap = (cap + 255) // 256 * 256
            buf = self.ctx.buffer(cap, label=name, chunked=chunked)
            self.buffers[name] = buf
        return buf


def groups(n, per=256):
    """Workgroups for ``n`` items at ``per`` items per workgroup (at least one)."""
    return max(1, (int(n) + per - 1) // per)
