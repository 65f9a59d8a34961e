"""The ablation switches (the paper's Tables 2-3): each changes its schedule, reaches the
schedule through TrainConfig, and changes what a prune step deletes. Each test fails if its
switch is ignored."""

import numpy as np
import pytest

from tsplus_wgpu.train.ablations import ABLATIONS, ablation_overrides
from tsplus_wgpu.train.schedules import SIGMA_FINAL, SIGMA_SOFT, Schedule


def test_sigma_decay_and_final():
    full = Schedule()
    assert full.sigma(0) == 1.0 and full.sigma(30000) == pytest.approx(SIGMA_FINAL, abs=1e-15)
    flat = Schedule(sigma_decay=False)
    assert all(flat.sigma(i) == SIGMA_FINAL for i in (0, 1, 5000, 15000, 30000, 40000))
    soft = Schedule(sigma_final=SIGMA_SOFT)
    assert SIGMA_SOFT == 0.1
    assert soft.sigma(0) == 1.0 and soft.sigma(30000) == pytest.approx(0.1)
    assert soft.sigma(15000) == pytest.approx(0.55)
    assert Schedule(sigma_decay=False, sigma_final=0.1).sigma(0) == pytest.approx(0.1)
    # quick runs scale nothing here: the decay is over the run either way
    assert Schedule(total=300, quick=True, sigma_final=0.1).sigma(300) == pytest.approx(0.1)
    for bad in (0.0, -1.0, 2.0):
        with pytest.raises(ValueError):
            Schedule(sigma_final=bad)


def test_free_opacity_has_no_floor():
    opaque, free = Schedule(), Schedule(opacity_mode="free")
    assert opaque.opacity_floor(5000) == pytest.approx(0.1) and opaque.opacity_floor(30000) == pytest.approx(0.9999)
    assert all(free.opacity_floor(i) == 0.0 for i in range(0, 30001, 250))
    assert not any(free.opacity_floor_changes(i) for i in range(1, 30001))
    q = Schedule(total=300, quick=True, opacity_mode="free")
    assert all(q.opacity_floor(i) == 0.0 for i in range(301))
    with pytest.raises(ValueError):
        Schedule(opacity_mode="glass")


def test_prune_criteria():
    assert Schedule().prune_criteria() == ("opacity", "weight", "size")
    assert Schedule(hard_prune=False).prune_criteria() == ("weight", "size")
    assert Schedule(weight_prune=False).prune_criteria() == ("opacity", "size")
    # the prune steps themselves stay where they are
    steps = [i for i in range(30001) if Schedule(hard_prune=False, weight_prune=False).is_prune_step(i)]
    assert steps == [i for i in range(30001) if Schedule().is_prune_step(i)]


def test_config_reaches_schedule_and_resume_keys():
    from tsplus_wgpu.train.trainer import TrainConfig
    s = TrainConfig().schedule()
    assert (s.hard_prune, s.weight_prune, s.sigma_decay, s.sigma_final, s.opacity_mode) == (True, True, True,
                                                                                          SIGMA_FINAL, "opaque")
    s = TrainConfig(hard_prune=False, weight_prune=False, sigma_decay=False, sigma_final=0.1,
                    opacity="free").schedule(views=5)
    assert s.prune_criteria() == ("size",)
    assert s.sigma(0) == pytest.approx(0.1) and s.opacity_floor(30000) == 0.0
    for key in ("hard_prune", "weight_prune", "sigma_decay", "sigma_final", "opacity"):
        assert key in TrainConfig.RESUME_KEYS


def test_ablation_table():
    from tsplus_wgpu.train.trainer import TrainConfig
    assert list(ABLATIONS) == ["baseline", "no-hard-prune", "no-weight-prune", "no-sigma-decay", "soft-opaque",
                               "hard-free", "soft-free"]
    sched = {name: TrainConfig(**ablation_overrides(name)).schedule() for name in ABLATIONS}
    assert sched["no-hard-prune"].prune_criteria() == ("weight", "size")
    assert sched["no-weight-prune"].prune_criteria() == ("opacity", "size")
    assert sched["no-sigma-decay"].sigma(0) == SIGMA_FINAL
    assert sched["soft-opaque"].sigma(30000) == pytest.approx(0.1) and sched["soft-opaque"].opacity_floor(30000) > 0.99
    assert sched["hard-free"].opacity_floor(30000) == 0.0 and sched["hard-free"].sigma(30000) == pytest.approx(1e-4)
    assert sched["soft-free"].opacity_floor(30000) == 0.0 and sched["soft-free"].sigma(30000) == pytest.approx(0.1)
    with pytest.raises(ValueError, match="no-such"):
        ablation_overrides("no-such")


@pytest.fixture(scope="module")
def tiny():
    from tsplus_wgpu.data import load_procedural
    return load_procedural("tiny")


def _pruned(renderer, tiny, **switches):
    """Triangles a prune step deletes from one fixed state: half the vertices at opacity 0.05
    (below the threshold), the first half of the triangles with max blending weight 0 (below it)."""
    from tsplus_wgpu.train.schedules import logit_from_opacity
    from tsplus_wgpu.train.trainer import TrainConfig, Trainer
    t = Trainer(tiny, TrainConfig(shell=False, **switches), renderer=renderer)   # no triangle exempt
    it = 4500                                   # the first prune step (floor still 0); densifying stopped
    assert t.sched.is_prune_step(it) and t.sched.opacity_floor(it) == 0.0
    t.topology.densify_stopped = "test: prune only"
    rng = np.random.default_rng(0)
    low = rng.random(t.n) < 0.5
    op = np.where(low, 0.05, 0.9)
    t.ctx.queue.write_buffer(t.params["logits"], 0, logit_from_opacity(op, t.sched.opacity_floor(it)).astype(
        np.float32).tobytes())
    mw = np.ones(t.m, np.float32)
    mw[: t.m // 2] = 0.0
    t.ctx.queue.write_buffer(t.topology.acc, 0, mw.tobytes())
    t.topology.seen = set(t.train_views)
    tris = t.triangles_host.copy()
    t.apply_topology(it)
    by_opacity = low[tris].any(axis=1)
    by_weight = mw == 0
    return t, tris, by_opacity, by_weight, t.topology.events[-1]


def test_prune_switches_change_what_is_deleted(renderer, tiny):
    t, tris, by_op, by_w, ev = _pruned(renderer, tiny)
    assert ev["pruned_opacity"] == int(by_op.sum()) and ev["pruned_weight"] == int((by_w & ~by_op).sum())
    base_m = t.m
    assert base_m <= int((~by_op & ~by_w).sum())
    t, _, _, _, ev = _pruned(renderer, tiny, hard_prune=False)
    assert "pruned_opacity" not in ev and ev["pruned_weight"] == int(by_w.sum())
    assert t.m > base_m and t.m <= int((~by_w).sum())
    t, _, _, _, ev = _pruned(renderer, tiny, weight_prune=False)
    assert "pruned_weight" not in ev and ev["pruned_opacity"] == int(by_op.sum())
    assert t.m > base_m and t.m <= int((~by_op).sum())


def test_trainer_follows_sigma_and_floor_switches(renderer, tiny):
    from tsplus_wgpu.train.trainer import TrainConfig, Trainer
    runs = {}
    for name, switches in (("base", {}), ("flat_free", dict(sigma_decay=False, opacity="free"))):
        t = Trainer(tiny, TrainConfig(iterations=20, quick=True, **switches), renderer=renderer)
        first = t.step(read_stats=True)
        while t.iteration < 20:
            t.step()
        runs[name] = (first, t.current_model().opacity)
    # sigma 1e-4 from the first step renders (and scores) another image than sigma ~0.95
    assert runs["flat_free"][0]["loss"] != pytest.approx(runs["base"][0]["loss"], rel=1e-3)
    # the quick floor reaches 0.9999 by iteration 16 of 20; free opacity has none
    assert runs["base"][1].min() >= 0.999
    assert np.isfinite(runs["flat_free"][1]).all() and runs["flat_free"][1].min() < 0.9


def test_train_cli_ablation_sets_config(tmp_path):
    import json

    from tsplus_wgpu.cli.main import main
    out = tmp_path / "run"
    rc = main(["train", "procedural:tiny", "--out", str(out), "--preset", "quick", "--iterations", "12",
               "--ablation", "no-sigma-decay", "--no-progress", "--log-every", "4"])
    assert rc == 0
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["sigma_decay"] is False and cfg["extra"]["ablation"] == "no-sigma-decay"
    assert cfg["hard_prune"] is True and cfg["sigma_final"] == 1e-4 and cfg["opacity"] == "opaque"
