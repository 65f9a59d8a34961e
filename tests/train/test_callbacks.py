"""Trainer.train(callbacks=...): the benchmarks' hook on the real loop (profiled steps on request,
one info per step, continuing with ``until``), and the vertex state / pure topology operations."""

import numpy as np
import pytest

from tsplus_wgpu.train import TrainCallback, VertexState
from tsplus_wgpu.train.profile import STAGES
from tsplus_wgpu.train.strategy import densify, prune

SCALED_500 = dict(quick_topology_epochs=0, quick_opacity_lr_scale=1)   # densify at 10 (tests/test_train_topology)


@pytest.fixture(scope="module")
def tiny():
    from tsplus_wgpu.data import load_procedural
    return load_procedural("tiny")


class Recorder(TrainCallback):
    def __init__(self, profile):
        self.profile, self.asked, self.infos = set(profile), [], []

    def wants_profile(self, trainer, it):
        self.asked.append((it, trainer.iteration))
        return it in self.profile

    def after_step(self, trainer, it, info):
        assert trainer.iteration == it
        self.infos.append(info)


def test_callbacks_see_every_step_and_profile_on_request(renderer, tiny):
    from tsplus_wgpu.train.trainer import TrainConfig, Trainer
    cfg = TrainConfig(iterations=300, quick=True, seed=3, log_every=0, **SCALED_500)
    plain = Trainer(tiny, cfg, renderer=renderer).train(progress=False, until=12)
    t = Trainer(tiny, cfg, renderer=renderer)
    cb, quiet = Recorder({3, 10}), TrainCallback()
    t.train(progress=False, until=7, callbacks=[cb, quiet])
    t.train(progress=False, until=12, callbacks=[cb])          # continues where it stopped
    assert t.iteration == 12 and [it for it, _ in cb.asked] == list(range(1, 13))
    assert all(before == it - 1 for it, before in cb.asked)
    assert [i["iteration"] for i in cb.infos] == list(range(1, 13))
    for info in cb.infos:
        it = info["iteration"]
        assert info["profiled"] == (it in {3, 10})
        assert info["topology"] == t.is_topology_step(it) == (it == 10)
        assert (info["step_times"] is None) == (it not in {3, 10})
        assert info["vertices"] > 0
    assert set(cb.infos[9]["step_times"]) == set(STAGES) | {"wall", "other"}
    assert cb.infos[9]["vertices"] > cb.infos[8]["vertices"]     # the densify step
    assert t.profile_method in ("timestamp queries", "host timing (per-stage submit + queue wait)")
    a, b = plain.state_arrays(), t.state_arrays()                # profiling and callbacks change nothing
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


def test_state_round_trip_and_pure_topology_ops(renderer, tiny):
    from tsplus_wgpu.train.trainer import TrainConfig, Trainer
    t = Trainer(tiny, TrainConfig(iterations=300, quick=True, seed=1, log_every=0, **SCALED_500), renderer=renderer)
    t.train(progress=False, until=3)
    s = t.read_state()
    assert (s.n, s.m, s.k) == (t.n, t.m, t.k) and s.max_weight.shape == (t.m,)
    before = t.state_arrays()
    t.set_state(s)                                               # installing what was read changes nothing
    after = t.state_arrays()
    for k in before:
        np.testing.assert_array_equal(before[k], after[k], err_msg=k)
    # prune: the triangles kept, unused vertices gone, rows of every per-vertex array moved together
    drop = np.zeros(s.m, bool)
    drop[: s.m // 2] = True
    p = prune(s, drop)
    assert p.m == s.m - drop.sum() and p.triangles.max() == p.n - 1
    old = np.unique(s.triangles[~drop])
    for key, arr in p.vertex_arrays().items():
        np.testing.assert_array_equal(arr, getattr(s, key)[old], err_msg=key)
    np.testing.assert_array_equal(p.max_weight, s.max_weight[~drop])
    # densify: one chosen triangle -> 4 children, 3 midpoints whose rows are edge means
    d = densify(s.astype(np.float64), np.array([0]), floor=0.0)
    assert (d.n, d.m) == (s.n + 3, s.m + 3)
    c0, c1, c2 = s.triangles[0]
    edges = ((c0, c1), (c1, c2), (c2, c0))
    for key in ("positions", "exp_avg_positions"):
        arr = getattr(s, key).astype(np.float64)
        want = {tuple(0.5 * (arr[i] + arr[j])) for i, j in edges}
        assert {tuple(x) for x in getattr(d, key)[s.n:]} == want, key
    assert isinstance(d, VertexState) and d.max_weight.shape == (d.m,)


def test_rate_estimate_reports_after_the_warm_up_and_after_the_first_prune(monkeypatch):
    """tsplus train's estimate: the wall rate over 20 steps after 5 warm-up ones, of what is left
    (of a resumed run too), and once more over the 20 steps after the first prune (the initial
    mesh makes the first steps the slowest); nothing more, and no second line without topology."""
    import time as clock
    from types import SimpleNamespace

    from tsplus_wgpu.train.callbacks import RateEstimate, duration_text
    from tsplus_wgpu.train.schedules import Schedule
    now = [0.0]
    monkeypatch.setattr(clock, "perf_counter", lambda: now[0])
    sched = Schedule(total=3000, quick=True)          # prunes at 450, 500, ...
    for first, topology, said in (
            (1, True, ["estimate: 2,975 iterations left at 1.0 it/s -> about 50 min (measured over steps 6-25)",
                       "estimate after the first prune: 2,530 iterations left at 4.0 it/s -> about 11 min "
                       "(measured over steps 451-470)"]),
            (1001, True, ["estimate: 1,975 iterations left at 1.0 it/s -> about 33 min (measured over steps "
                          "1006-1025)", "estimate after the first prune: 1,930 iterations left at 4.0 it/s -> about "
                          "8 min (measured over steps 1051-1070)"]),
            (1, False, ["estimate: 2,975 iterations left at 1.0 it/s -> about 50 min (measured over steps 6-25)"])):
        trainer = SimpleNamespace(config=SimpleNamespace(iterations=3000, topology=topology), sched=sched)
        lines = []
        cb = RateEstimate(report=lines.append)
        pruned = False
        for it in range(first, first + 1200):
            now[0] += 3.0 if it - first < 5 else (0.25 if pruned else 1.0)     # slow warm-up steps are not counted
            cb.after_step(trainer, it, {})
            pruned = pruned or (it - first >= 25 and sched.is_prune_step(it))
        assert lines == said
    assert [duration_text(s) for s in (42, 900, 4 * 3600, 3 * 86400)] == ["42 s", "15 min", "4.0 h", "3.0 days"]


def test_the_estimate_after_the_first_prune_counts_the_prunes_to_come(monkeypatch):
    """A paper-scale run on a GPU (the H200's office at 960x540): 20 ms steps, and a first prune
    that holds the step 40 s more. The estimate after it takes the 51 prunes still to come at
    that cost (25,480 / 50 s + 51 x 40 s, 42 min, not the steps' 8 min); on a CPU the prune of a
    small model costs under a second and the line is the plain one (the test above)."""
    import time as clock
    from types import SimpleNamespace

    from tsplus_wgpu.train.callbacks import RateEstimate
    from tsplus_wgpu.train.schedules import Schedule
    now = [0.0]
    monkeypatch.setattr(clock, "perf_counter", lambda: now[0])
    sched = Schedule(total=30000)                     # prunes every 500 from 4,500: 52
    trainer = SimpleNamespace(config=SimpleNamespace(iterations=30000, topology=True), sched=sched)
    lines = []
    cb = RateEstimate(report=lines.append)
    for it in range(1, 4600):
        now[0] += 0.02 + (40.0 if sched.is_prune_step(it) else 0.0)
        cb.after_step(trainer, it, {})
    assert lines == ["estimate: 29,975 iterations left at 50.0 it/s -> about 10 min (measured over steps 6-25)",
                     "estimate after the first prune: 25,480 iterations left at 50.0 it/s and 51 more prunes at "
                     "about 40 s each (the first one's) -> about 42 min (measured over steps 4501-4520)"]


def test_the_first_estimate_takes_the_steps_after_the_first_prune_at_the_time_models_rate(monkeypatch):
    """With ``later_cost`` (a CPU run's time model: an iteration after the first prune costs
    0.25x one before it), the first estimate counts the 424 iterations before the prune at 450
    at the measured 1.0 it/s and the 2,551 from it on at 4.0 it/s: 424 + 637.75 s, not 2,975 s;
    the estimate after the prune is the measured one as before."""
    import time as clock
    from types import SimpleNamespace

    from tsplus_wgpu.train.callbacks import RateEstimate
    from tsplus_wgpu.train.schedules import Schedule
    now = [0.0]
    monkeypatch.setattr(clock, "perf_counter", lambda: now[0])
    sched = Schedule(total=3000, quick=True)
    trainer = SimpleNamespace(config=SimpleNamespace(iterations=3000, topology=True), sched=sched)
    lines = []
    cb = RateEstimate(report=lines.append, later_cost=0.25)
    pruned = False
    for it in range(1, 600):
        now[0] += 3.0 if it <= 5 else (0.5 if pruned else 1.0)
        cb.after_step(trainer, it, {})
        pruned = pruned or (it >= 25 and sched.is_prune_step(it))
    assert lines == ["estimate: 2,975 iterations left, at 1.0 it/s until the first prune (iteration 450) and about "
                     "4.0 it/s after it by the time model -> about 18 min (measured over steps 6-25)",
                     "estimate after the first prune: 2,530 iterations left at 2.0 it/s -> about 21 min "
                     "(measured over steps 451-470)"]


def test_a_slower_machine_is_told_the_iterations_that_fit_the_planned_time(monkeypatch):
    """A planned run (``planned``: the plan's 660 s and what fits them ``r`` times slower) on a
    machine that takes 2x: after the estimate that follows the first prune, one line names the
    iterations that would fit, with the slowdown measured over the whole run so far; none on a
    machine as fast as the plan, none without a plan, and without topology after the only estimate."""
    import time as clock
    from types import SimpleNamespace

    from tsplus_wgpu.train.callbacks import RateEstimate
    from tsplus_wgpu.train.schedules import Schedule
    now = [0.0]
    monkeypatch.setattr(clock, "perf_counter", lambda: now[0])
    asked = []

    def fits(slower):
        asked.append(round(slower, 3))
        return 100 * int(3000 / slower / 100)

    def run(step_s, topology=True, planned=(660.0, fits)):
        sched = Schedule(total=3000, quick=True)        # first prune at 450
        trainer = SimpleNamespace(config=SimpleNamespace(iterations=3000, topology=topology), sched=sched)
        lines, now[0] = [], 0.0
        cb = RateEstimate(report=lines.append, planned=planned)
        for it in range(1, 600):
            now[0] += step_s
            cb.after_step(trainer, it, {})
        return lines

    slow = run(0.44)                    # 3000 x 0.44 s = 1,320 s: 2x the plan's 660
    assert len(slow) == 3 and slow[2] == ("this machine: about 2.0x the 11 min the plan expected; --iterations 1,500 "
                                          "would fit that time (a shorter run, not this one)")
    assert len(asked) == 1 and abs(asked[0] - 2.0) < 0.01     # timed from the end of the first step
    assert len(run(0.22)) == 2          # as the plan expected: no hint
    assert len(run(0.3)) == 2           # 1.36x: under SLOWER
    assert len(run(0.44, planned=None)) == 2
    alone = run(0.44, topology=False)   # the only estimate, then the hint
    assert len(alone) == 2 and alone[1].startswith("this machine: about 2.0x")
