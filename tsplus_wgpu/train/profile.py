"""Per-stage time of one training step: ``Trainer.step(profile=True)`` (off by default; a step
that is not profiled runs exactly the code it always did).

Stages (the names ``tsplus bench`` reports), from the kernels that make them up:

* ``projection``: ``sh_to_color``, ``project_triangles``
* ``binning``: ``bin_rows``, ``bin_items``, ``bin_count``, ``bin_emit``, ``tile_ranges``
* ``sort``: ``depth_sort``, ``tile_sort`` (radix sorts of the forward)
* ``forward``: ``rasterize_forward`` (the blend)
* ``loss``: area downsampling (s > 1), L1 + D-SSIM and its gradient, packing the backward's input
* ``backward``: ``backward_prepare``, ``rasterize_backward``, the pair sort and sum, ``project_backward``
* ``gather``: corner sort and sum to vertices, ``vertex_backward``
* ``optimizer``: opacity regulariser, chain rule of the activation, Adam, activation
* ``topology``: the max-weight accumulation per step, plus the host-side edit (prune / densify,
  buffer re-creation) on topology steps

Timing: with timestamp queries (the adapter's ``timestamp-query`` feature) every stage is the sum
of its compute passes' GPU time; without them each stage is submitted on its own and timed on
the host after waiting for the queue. The topology edit is host work and always host-timed.
``wall`` is the whole step on the host (waiting for the device at its end), ``other`` what the
stages do not account for (Python, submission, the forward's size readbacks, logging readbacks).
"""

from __future__ import annotations

import time

from ..gpu.recorder import Recorder

STAGES = ("projection", "binning", "sort", "forward", "loss", "backward", "gather", "optimizer", "topology")

#: kernel (or host-timing) label -> stage
KERNEL_STAGE = {
    "sh_to_color": "projection", "project_triangles": "projection",
    "bin_rows": "binning", "bin_items": "binning", "bin_count": "binning", "bin_emit": "binning",
    "tile_ranges": "binning",
    "depth_sort": "sort", "tile_sort": "sort",
    "rasterize_forward": "forward",
    "backward_prepare": "backward", "rasterize_backward": "backward", "pair_sort": "backward",
    "pair_reduce": "backward", "project_backward": "backward",
    "corner_sort": "gather", "corner_sum": "gather", "vertex_backward": "gather",
}


class StepProfiler:
    """Collects one step's stage times (ms). One per trainer, reused (its query sets are)."""

    def __init__(self, ctx):
        self.ctx = ctx
        self.timestamps = bool(ctx.features.timestamps)
        # one query set per trainer-side stage: the kernels of a stage need no labels of their own
        self.profilers = {k: Recorder(ctx) for k in ("loss", "optimizer", "topology")} if self.timestamps else {}
        self.clock = Recorder(ctx, timestamps=False)   # host timing: marks, host work, the wall time
        self.times = {}
        self.kernels = {}

    @staticmethod
    def describe(timestamps):
        """The timing method's name with or without timestamp queries."""
        return "timestamp queries" if timestamps else "host timing (per-stage submit + queue wait)"

    @property
    def method(self):
        return self.describe(self.timestamps)

    def profiler(self, stage):
        """The :class:`~tsplus_wgpu.gpu.Recorder` to hand to ``stage``'s kernels (None: host timing)."""
        return self.profilers.get(stage)

    def begin(self):
        self.clock.start()
        self.times = {k: 0.0 for k in STAGES}
        self.kernels = {}
        self.t0 = self.clock.t

    def add(self, stage, ms):
        self.times[stage] = self.times.get(stage, 0.0) + float(ms)

    def add_kernels(self, timings):
        """A renderer's per-kernel timings (forward or backward, ``{label: ms}``)."""
        for label, ms in timings.items():
            self.kernels[label] = self.kernels.get(label, 0.0) + float(ms)
            self.add(KERNEL_STAGE.get(label, "backward" if "backward" in label else "forward"), ms)
        self.clock.restart()

    def mark(self, stage):
        """The work of ``stage`` was just submitted: with timestamps nothing to do until
        :meth:`finish`; on the host wait for it and charge the time since the last mark."""
        if self.timestamps:
            return
        self.add(stage, self.clock.lap(stage))

    def host(self, stage, seconds):
        self.add(stage, seconds * 1e3)
        self.clock.restart()

    def finish(self):
        """``{stage: ms, ..., "wall": ms, "other": ms}`` of the step."""
        for stage, prof in self.profilers.items():
            self.add(stage, sum(prof.resolve().values()))
        self.ctx.wait()
        wall = (time.perf_counter() - self.t0) * 1e3
        out = {k: self.times.get(k, 0.0) for k in STAGES}
        out["wall"] = wall
        out["other"] = max(0.0, wall - sum(out[k] for k in STAGES))
        return out


__all__ = ["STAGES", "KERNEL_STAGE", "StepProfiler"]
