"""Hooks on the real training loop (:meth:`~.trainer.Trainer.train`): :class:`TrainCallback`.

The benchmarks and any other client observe training through these instead of running a copy
of the loop. Before iteration ``it`` (1-based) runs, every callback is asked
:meth:`~TrainCallback.wants_profile`; if any says True the step runs with per-stage profiling
(:mod:`.profile`; a profiled step computes exactly what an unprofiled one does). After the step,
:meth:`~TrainCallback.after_step` gets ``info``:

* ``iteration``: ``it``
* ``profiled``: whether the step was profiled
* ``step_times``: ``{stage: ms, ..., "wall": ms, "other": ms}`` of a profiled step, else None
* ``topology``: whether this step pruned or densified
* ``vertices``: the model's vertex count after the step (``trainer.n``)
"""

from __future__ import annotations


class TrainCallback:
    """No-op base: override what you need."""

    def wants_profile(self, trainer, it) -> bool:
        """Whether iteration ``it`` (not yet run) should be profiled per stage."""
        return False

    def after_step(self, trainer, it, info) -> None:
        """Called after iteration ``it`` with the step's ``info`` (see the module docstring)."""


__all__ = ["TrainCallback"]
