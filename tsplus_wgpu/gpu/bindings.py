"""What a dispatch costs the host, made once: uniform buffers by content and bind groups by
the buffers they bind (:class:`UniformCache`, :class:`BindGroupCache`; both owned by
:class:`~tsplus_wgpu.gpu.context.GpuContext`).

Making a uniform buffer and a bind group costs the host about 0.1 and 0.25 ms through
wgpu-py (a 2-core AMD EPYC), about as long as a small kernel runs, and a training step
dispatches about 80 kernels, most with the same buffers and uniform values as the step
before. On a GPU, where a step's kernels take 1-2 ms, that host work is much of the step.

- A uniform buffer is never written after it is made, so dispatches whose uniform structs
  have the same bytes share one buffer. The cache keeps the ``capacity`` most recently used.
- A bind group is kept for its layout and the exact buffers, offsets and sizes it binds, as
  long as all those buffers live: when Python drops a buffer, every bind group that binds it
  is dropped too (one finalizer per buffer), so a cached bind group never keeps a freed
  buffer's device memory alive and is never served for a new buffer that reuses a dead
  one's ``id``. At most ``capacity`` are kept (the least recently used go first).
"""

from __future__ import annotations

import threading
import weakref
from collections import OrderedDict


class UniformCache:
    """Immutable uniform buffers by content (the ``capacity`` most recently used)."""

    def __init__(self, make, capacity=1024):
        self.make = make              # (bytes, label) -> buffer
        self.capacity = int(capacity)
        self.buffers = OrderedDict()
        self.made = 0
        self.lock = threading.Lock()

    def get(self, data: bytes, label=""):
        with self.lock:
            buf = self.buffers.get(data)
            if buf is not None:
                self.buffers.move_to_end(data)
                return buf
        buf = self.make(data, label)
        with self.lock:
            self.made += 1
            self.buffers[data] = buf
            while len(self.buffers) > self.capacity:
                self.buffers.popitem(last=False)
        return buf


class BindGroupCache:
    """Bind groups by (layout, ``[(binding, buffer, offset, size)]``) while their buffers live."""

    def __init__(self, device, capacity=4096):
        self.device = device
        self.capacity = int(capacity)
        self.groups = OrderedDict()   # key -> bind group
        self.users = {}               # id(buffer) -> keys of the groups that bind it
        self.made = 0
        self.lock = threading.RLock()

    def get(self, layout, entries):
        """The bind group of ``layout`` binding ``entries``: ``[(binding, buffer, offset, size)]``.
        ``layout`` must live as long as the cache (the context keeps every pipeline's)."""
        key = (id(layout),) + tuple((slot, id(buf), int(off), int(size)) for slot, buf, off, size in entries)
        with self.lock:
            group = self.groups.get(key)
            if group is not None:
                self.groups.move_to_end(key)
                return group
        group = self.device.create_bind_group(layout=layout, entries=[
            {"binding": slot, "resource": {"buffer": buf, "offset": int(off), "size": int(size)}}
            for slot, buf, off, size in entries])
        with self.lock:
            self.made += 1
            self.groups[key] = group
            for _, buf, _, _ in entries:
                keys = self.users.get(id(buf))
                if keys is None:
                    keys = self.users[id(buf)] = set()
                    weakref.finalize(buf, self._dead, id(buf)).atexit = False
                keys.add(key)
            while len(self.groups) > self.capacity:
                self._drop(next(iter(self.groups)))
        return group

    def _drop(self, key):
        self.groups.pop(key, None)
        for _, buf_id, _, _ in key[1:]:
            keys = self.users.get(buf_id)
            if keys is not None:
                keys.discard(key)

    def _dead(self, buf_id):
        """A buffer was dropped: so are the bind groups that bind it."""
        with self.lock:
            for key in self.users.pop(buf_id, ()):
                self._drop(key)

    def __len__(self):
        return len(self.groups)


__all__ = ["UniformCache", "BindGroupCache"]
