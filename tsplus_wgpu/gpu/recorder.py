"""Recording and timing of device work: one :class:`Recorder` submits command encoders and
collects per-label times (ms), from timestamp queries when the device has them, on the host
otherwise; :func:`host_time` times one call on the host."""

from __future__ import annotations

import time

import numpy as np
import wgpu

from .context import GpuContext


class Recorder:
    """Records work into command encoders, submits them and times it per label.

    Args:
        ctx: the device.
        profile: collect times; with False the recorder only records and submits.
        timestamps: time with timestamp queries (the default where the device has them) or,
            with False, on the host: every :meth:`flush` then submits, waits for the queue and
            charges the time since the previous one to its label.
        capacity: timestamp queries (two per timed compute pass).

    Kernels get the recorder as their ``profiler`` argument (:attr:`profiler`): with
    timestamps each compute pass writes its begin and end under its label
    (:meth:`writes`), and a label's time is the sum of its passes' GPU time.
    """

    def __init__(self, ctx: GpuContext, profile=True, timestamps=None, capacity=512):
        self.ctx = ctx
        if timestamps is None:
            timestamps = bool(ctx.features.timestamps)
        elif timestamps and not ctx.features.timestamps:
            raise RuntimeError("timestamp queries are not available on this device")
        self.timestamps = bool(profile and timestamps)
        self.host_timing = bool(profile and not timestamps)
        self.capacity = capacity
        self.query_set = ctx.device.create_query_set(type="timestamp", count=capacity) if self.timestamps else None
        self.labels = []          # label of each timed pass, in query order
        self.times = {}           # host-timed labels: {label: ms}
        self.encoder = ctx.device.create_command_encoder()
        self.t = time.perf_counter()

    @property
    def profiler(self):
        """What to hand to the kernels' ``profiler`` argument: this recorder where it writes
        timestamps, else None (the kernels then record plain passes)."""
        return self if self.timestamps else None

    def writes(self, label):
        """``timestamp_writes`` of the next compute pass, labelled ``label`` (None: untimed)."""
        if not self.timestamps:
            return None
        i = len(self.labels)
        if 2 * i + 2 > self.capacity:
            return None
        self.labels.append(label)
        return {"query_set": self.query_set, "beginning_of_pass_write_index": 2 * i,
                "end_of_pass_write_index": 2 * i + 1}

    def start(self):
        """Start the host clock (with host timing after waiting for earlier work)."""
        if self.host_timing:
            self.ctx.wait()
        self.t = time.perf_counter()

    def restart(self):
        """Restart the host clock without waiting (work since then is charged to the next lap)."""
        self.t = time.perf_counter()

    def add(self, label, ms):
        self.times[label] = self.times.get(label, 0.0) + float(ms)

    def lap(self, label):
        """With host timing: wait for the device and charge the time since the last lap to
        ``label``; returns those ms. Otherwise nothing (returns 0)."""
        if not self.host_timing:
            return 0.0
        self.ctx.wait()
        now = time.perf_counter()
        ms = (now - self.t) * 1e3
        self.add(label, ms)
        self.t = now
        return ms

    def submit(self, label=None):
        """Submit the current encoder, open a new one, and (host timing) charge ``label``."""
        self.ctx.queue.submit([self.encoder.finish()])
        self.encoder = self.ctx.device.create_command_encoder()
        if label is not None:
            self.lap(label)

    def flush(self, label, force=False):
        """End of the work of ``label``: submitted (and timed) with host timing, or when
        ``force`` (the host reads a result next); otherwise recording goes on in one encoder."""
        if self.host_timing or force:
            self.submit(label)

    def resolve(self):
        """``{label: ms}`` of everything timed so far (call after the work is submitted);
        resets the recorder's times."""
        out = dict(self.times)
        n = 2 * len(self.labels)
        if n:
            c = self.ctx
            buf = c.device.create_buffer(size=8 * n, usage=wgpu.BufferUsage.QUERY_RESOLVE | wgpu.BufferUsage.COPY_SRC)
            enc = c.device.create_command_encoder()
            enc.resolve_query_set(self.query_set, 0, n, buf, 0)
            c.queue.submit([enc.finish()])
            ts = c.read(buf, np.uint64)
            for i, label in enumerate(self.labels):
                out[label] = out.get(label, 0.0) + max(0, int(ts[2 * i + 1]) - int(ts[2 * i])) * 1e-6
        self.labels = []
        self.times = {}
        return out


def host_time(ctx: GpuContext, fn):
    """Run ``fn()`` (which submits work) and wait for the device; returns seconds."""
    ctx.wait()
    t0 = time.perf_counter()
    fn()
    ctx.wait()
    return time.perf_counter() - t0
