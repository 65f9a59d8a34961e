"""Hooks on the real training loop (:meth:`~.trainer.Trainer.train`): :class:`TrainCallback`.

The benchmarks and any other client observe training through these instead of running a copy
of the loop; :class:`RateEstimate` (``tsplus train``'s early time estimate) is one. Before
iteration ``it`` (1-based) runs, every callback is asked :meth:`~TrainCallback.wants_profile`;
if any says True the step runs with per-stage profiling
(:mod:`.profile`; a profiled step computes exactly what an unprofiled one does). After the step,
:meth:`~TrainCallback.after_step` gets ``info``:

* ``iteration``: ``it``
* ``profiled``: whether the step was profiled
* ``step_times``: ``{stage: ms, ..., "wall": ms, "other": ms}`` of a profiled step, else None
* ``topology``: whether this step pruned or densified
* ``vertices``: the model's vertex count after the step (``trainer.n``)
"""

from __future__ import annotations

import time

#: :class:`RateEstimate` says how to shorten a planned run when the machine takes this many times
#: the time the plan's model expected (the plan's reference machine: docs/measurements.md)
SLOWER = 1.5


class TrainCallback:
    """No-op base: override what you need."""

    def wants_profile(self, trainer, it) -> bool:
        """Whether iteration ``it`` (not yet run) should be profiled per stage."""
        return False

    def after_step(self, trainer, it, info) -> None:
        """Called after iteration ``it`` with the step's ``info`` (see the module docstring)."""


def duration_text(seconds):
    """``seconds`` in the unit a person plans with: s, min, h or days."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 90 * 60:
        return f"{seconds / 60:.0f} min"
    if seconds < 48 * 3600:
        return f"{seconds / 3600:.1f} h"
    return f"{seconds / 86400:.1f} days"


class RateEstimate(TrainCallback):
    """Says early how long the run will take: the wall rate over ``steps`` steps after the
    first ``warmup`` ones (those compile pipelines and fill caches) times the iterations left to
    ``trainer.config.iterations``. ``report(line)`` gets e.g. "estimate: 3,000 iterations at 3.4
    it/s -> about 15 min (measured over steps 6-25)". The first steps are the slowest of a run:
    until the first prune the whole initial Delaunay mesh is drawn (the cup: 100k triangles
    until iteration 601 of 3000, then a fraction of them). So the estimate is said once more,
    measured over ``steps`` steps after the first prune ("estimate after the first prune: ..."),
    with the prunes still to come at the first one's cost where they add a tenth or more (a
    paper-scale model's prune is host work of many seconds). Later steps may still run at another
    rate (the supersampled last third, a model densification grew): the lines answer "minutes or
    days?", they are not a promise.

    ``later_cost`` (optional): how many times an iteration after the first prune costs one
    before it, by a time model (``tsplus train`` on a CPU adapter:
    :func:`~tsplus_wgpu.cli.plan.cpu_late_ratio`). With it the first estimate, made before the
    first prune, takes the iterations after the prune at the measured rate / ``later_cost``
    instead of at the slow rate of the initial mesh.

    ``planned`` (optional): ``(seconds, iterations_for)``, the training seconds a planned run
    (``tsplus train`` on a CPU adapter choosing the iterations) was given by the plan's time model
    and a function from a slowdown ``r`` to the iterations that fit those seconds on a machine
    ``r`` times slower. Where the last estimate (the one after the first prune, or the only one)
    puts the whole run at :data:`SLOWER` x those seconds or more, one more line names the
    iterations that would: the plan itself never reads a clock (the same command trains the same
    model anywhere), so shortening the run is the user's call."""

    def __init__(self, report=print, warmup=5, steps=20, later_cost=None, planned=None):
        self.report, self.warmup, self.steps = report, max(1, int(warmup)), max(1, int(steps))
        self.later_cost, self.planned = later_cost, planned
        self.began = None              # the clock after the first step
        self.first = self.start = None
        self.pruned_at = None          # (iteration, clock, its step's seconds) of the first prune
        self.last = None               # the clock at the last step
        self.done_after_prune = False

    def _say(self, trainer, it, start, what, edit_s=0.0):
        rate = self.steps / max(time.perf_counter() - start, 1e-9)
        total = int(trainer.config.iterations)
        left = total - it
        prune = self._first_prune_ahead(trainer, it) if self.later_cost and what == "estimate" else None
        if prune is None:
            seconds, edits = left / rate, ""
            # the first prune's own cost (its step less a step's time), for every prune to come,
            # where that counts: a million-vertex model's prune held an H200 30-46 s among 20 ms steps
            edit_s = max(0.0, edit_s - 1.0 / rate)
            sched = getattr(trainer, "sched", None)
            prunes = sum(1 for i in range(it + 1, total + 1) if sched.is_prune_step(i)) if edit_s >= 1.0 else 0
            if prunes and prunes * edit_s >= 0.1 * seconds:
                seconds += prunes * edit_s
                edits = f" and {prunes:,} more prunes at about {duration_text(edit_s)} each (the first one's)"
            self.report(f"{what}: {left:,} iterations left at {rate:.1f} it/s{edits} -> about "
                        f"{duration_text(seconds)} (measured over steps {it - self.steps + 1}-{it})")
            return seconds
        later = rate / self.later_cost
        seconds = (prune - 1 - it) / rate + (total - prune + 1) / later
        self.report(f"{what}: {left:,} iterations left, at {rate:.1f} it/s until the first prune (iteration "
                    f"{prune:,}) and about {later:.1f} it/s after it by the time model -> about "
                    f"{duration_text(seconds)} (measured over steps {it - self.steps + 1}-{it})")
        return seconds

    def _hint(self, trainer, left_seconds):
        """The line of ``planned`` (see the class), when this machine is :data:`SLOWER` or more."""
        if self.planned is None:
            return
        planned, iterations_for = self.planned
        ratio = (time.perf_counter() - self.began + left_seconds) / max(float(planned), 1e-9)
        fewer = iterations_for(ratio) if ratio >= SLOWER else None
        if fewer is not None and fewer < int(trainer.config.iterations):
            self.report(f"this machine: about {ratio:.1f}x the {duration_text(planned)} the plan expected; "
                        f"--iterations {fewer:,} would fit that time (a shorter run, not this one)")

    @staticmethod
    def _first_prune_ahead(trainer, it):
        """The run's first prune step when it comes after ``it`` (None: topology off, no prune,
        or the first one is past)."""
        sched = getattr(trainer, "sched", None)
        if sched is None or not trainer.config.topology:
            return None
        first = sched.first_prune_step()
        return first if first is not None and first > it else None

    def after_step(self, trainer, it, info):
        sched = getattr(trainer, "sched", None)
        if self.first is None:
            self.first = it
            self.last = self.began = time.perf_counter()
        done = it - self.first + 1
        if done == self.warmup:
            self.start = time.perf_counter()
        elif done == self.warmup + self.steps:
            left = self._say(trainer, it, self.start, "estimate")
            if sched is None or not trainer.config.topology or not any(
                    sched.is_prune_step(i) for i in range(it + 1, int(trainer.config.iterations) + 1)):
                self._hint(trainer, left)              # no estimate after a prune to come
        if self.done_after_prune or sched is None or not trainer.config.topology:
            return
        now, last = time.perf_counter(), self.last
        self.last = now
        if self.pruned_at is None and done > self.warmup + self.steps and sched.is_prune_step(it):
            self.pruned_at = (it, now, now - last)       # the prune's step, its edit included
        elif self.pruned_at is not None and it - self.pruned_at[0] == self.steps:
            left = self._say(trainer, it, self.pruned_at[1], "estimate after the first prune", edit_s=self.pruned_at[2])
            self.done_after_prune = True
            self._hint(trainer, left)


__all__ = ["TrainCallback", "RateEstimate", "duration_text"]
