"""Trainer.step(profile=True): every stage timed, nothing else changes (bit-identical parameters
against unprofiled steps, topology edits included); the host-timing fallback."""

import math

import numpy as np
import pytest

from tsplus_wgpu.train.profile import STAGES, StepProfiler

SCALED_500 = dict(quick_topology_epochs=0, quick_opacity_lr_scale=1)   # densify at 10 (tests/test_train_topology)


@pytest.fixture(scope="module")
def tiny():
    from tsplus_wgpu.data import load_procedural
    return load_procedural("tiny")


def _run(renderer, tiny, profile_steps, host=False, steps=11):
    from tsplus_wgpu.train.trainer import TrainConfig, Trainer
    t = Trainer(tiny, TrainConfig(iterations=300, quick=True, seed=3, **SCALED_500), renderer=renderer)
    if host:
        sp = t.profiler = StepProfiler(t.ctx)
        sp.timestamps, sp.profilers = False, {}
    times = {}
    while t.iteration < steps:
        it = t.iteration + 1
        t.step(profile=it in profile_steps)
        if it in profile_steps:
            times[it] = dict(t.step_times)
    return t, times


def test_profiled_steps_change_nothing_and_time_every_stage(renderer, tiny):
    a, _ = _run(renderer, tiny, ())
    b, times = _run(renderer, tiny, set(range(1, 12)))
    assert not hasattr(a, "step_times")
    sa, sb = a.state_arrays(), b.state_arrays()
    assert sa.keys() == sb.keys()
    for k in sa:
        np.testing.assert_array_equal(sa[k], sb[k], err_msg=k)
    assert b.sched.is_densify_step(10)
    for it, tm in times.items():
        assert set(tm) == set(STAGES) | {"wall", "other"}
        assert all(math.isfinite(v) and v >= 0 for v in tm.values())
        for st in ("projection", "binning", "sort", "forward", "loss", "backward", "gather", "optimizer"):
            assert tm[st] > 0, (it, st)
        assert tm["wall"] >= sum(tm[s] for s in STAGES) - 1e-6 or renderer.ctx.features.timestamps
    # the densify step's host edit is charged to topology
    assert times[10]["topology"] > max(times[i]["topology"] for i in (8, 9, 11))


def test_host_timing_fallback(renderer, tiny):
    t, times = _run(renderer, tiny, {2, 3}, host=True, steps=3)
    for tm in times.values():
        assert tm["loss"] > 0 and tm["optimizer"] > 0 and tm["topology"] > 0
        assert tm["wall"] >= sum(tm[s] for s in ("loss", "optimizer", "topology"))
