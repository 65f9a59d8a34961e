"""Host class of shaders/topology/: the running maximum of each triangle's blending weight.
Twin: :func:`tsplus_wgpu.reference.topology.max_weight_accumulate`."""

from __future__ import annotations

from ..gpu import Stage


class MaxWeightAccumulate(Stage):
    """``acc [M] = weights`` (``reset``) or ``max(acc, weights)`` (f32, weights >= 0)."""
    stage = "max_weight_accumulate"

    def __call__(self, enc, weights, acc, m, reset=False, profiler=None):
        ap = self.uniform("AccParams", num_triangles=m, reset=int(bool(reset)))
        self.dispatch(enc, self.groups(m), dict(ap=ap, weights=weights, acc=acc), profiler)
