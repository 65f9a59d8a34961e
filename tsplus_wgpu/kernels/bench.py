"""Host class of shaders/bench/peak_fma.wgsl: the device's peak FMA rate. Twin:
:func:`tsplus_wgpu.reference.bench.peak_fma`."""

from __future__ import annotations

from ..gpu import Stage


class PeakFma(Stage):
    """``iterations`` FMA steps of ``CHAINS`` vec4 chains per invocation; ``sink`` (vec4, one per
    invocation) is written only in the never-taken sentinel branch."""
    stage = "peak_fma"

    def __call__(self, enc, sink, groups, iterations, profiler=None):
        pp = self.uniform("PeakParams", iterations=iterations)
        self.dispatch(enc, groups, dict(pp=pp, sink=sink), profiler)

    def flop(self, groups, iterations):
        """Floating-point operations of one dispatch of ``groups`` workgroups."""
        return int(groups) * self.invocations * int(iterations) * self.const("FLOP_PER_ITERATION")
