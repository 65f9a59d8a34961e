import math

import numpy as np
import pytest

from tsplus_wgpu.train.schedules import (Schedule, logit_from_opacity, opacity_from_logit,
                                         reinvert_logits)

FULL = Schedule()
INDOOR = Schedule(indoor=True)


def test_position_lr():
    assert FULL.position_lr(0) == 0.0 and FULL.position_lr(999) == 0.0
    assert FULL.position_lr(1000) == pytest.approx(0.0015 * 100 ** (-1000 / 30000), rel=1e-12)
    assert FULL.position_lr(30000) == pytest.approx(0.0015 / 100, rel=1e-12)
    assert FULL.position_lr(40000) == pytest.approx(0.0015 / 100, rel=1e-12)
    # log-linear: the log is affine in the iteration
    l1, l2, l3 = (math.log(FULL.position_lr(i)) for i in (3000, 9000, 15000))
    assert l2 - l1 == pytest.approx(l3 - l2, rel=1e-12)
    assert FULL.position_lr(15000) == pytest.approx(0.0015 / 10, rel=1e-12)
    assert FULL.position_lr(15000, scale=2.0) == pytest.approx(0.0003, rel=1e-12)


def test_constant_lrs():
    assert FULL.sh_dc_lr() == 0.0016 and INDOOR.sh_dc_lr() == 0.004
    assert FULL.sh_rest_lr() == pytest.approx(0.0016 / 20) and INDOOR.sh_rest_lr() == pytest.approx(0.004 / 20)
    assert FULL.opacity_lr() == 0.03 and INDOOR.opacity_lr() == 0.05


def test_sh_degree():
    assert [FULL.sh_degree(i) for i in (0, 999, 1000, 1999, 2000, 2999, 3000, 29999)] == [0, 0, 1, 1, 2, 2, 3, 3]


def test_sigma():
    assert FULL.sigma(0) == 1.0
    assert FULL.sigma(30000) == pytest.approx(0.0001, abs=1e-15)
    assert FULL.sigma(15000) == pytest.approx((1.0 + 0.0001) / 2)
    assert FULL.sigma(31000) == pytest.approx(0.0001, abs=1e-15)
    assert Schedule(total=100).sigma(100) == pytest.approx(0.0001, abs=1e-15)


def test_opacity_floor():
    f = FULL.opacity_floor
    assert f(0) == 0.0 and f(4999) == 0.0
    assert f(5000) == pytest.approx(0.1) and f(5499) == pytest.approx(0.1)
    assert f(5500) == pytest.approx(0.1 + 0.8999 * 500 / 19000)
    assert f(14500) == pytest.approx(0.1 + 0.8999 * 0.5)
    assert f(23999) == pytest.approx(0.1 + 0.8999 * 18500 / 19000)
    assert f(24000) == pytest.approx(0.9999) and f(30000) == pytest.approx(0.9999)
    changes = [i for i in range(1, 30001) if FULL.opacity_floor_changes(i)]
    assert changes == list(range(5000, 24001, 500))


def test_logit_reinversion_keeps_opacity():
    rng = np.random.default_rng(0)
    w = rng.normal(0, 3, 1000)
    o = opacity_from_logit(w, 0.1)
    w2 = reinvert_logits(w, 0.1, 0.3)
    o2 = opacity_from_logit(w2, 0.3)
    above = o > 0.3 + 1e-5
    np.testing.assert_allclose(o2[above], o[above], rtol=1e-12)
    assert np.all(o2[~above] >= 0.3) and np.all(o2[~above] <= 0.3 + 2e-6)   # raised to the floor
    assert np.all(np.isfinite(w2))
    np.testing.assert_allclose(logit_from_opacity(opacity_from_logit(w, 0.0), 0.0), w, atol=1e-9)
    assert np.isfinite(reinvert_logits(np.array([50.0, -50.0]), 0.5, 0.9999)).all()
    # initial opacity 0.28 at m = 0 survives the first floor 0.1
    w0 = logit_from_opacity(0.28, 0.0)
    assert opacity_from_logit(reinvert_logits(w0, 0.0, 0.1), 0.1) == pytest.approx(0.28, rel=1e-12)
    with pytest.raises(ValueError):
        logit_from_opacity(0.5, 1.0)


def test_pruning():
    steps = [i for i in range(30001) if FULL.is_prune_step(i)]
    assert steps[:3] == [4500, 5000, 5500] and steps[-1] == 30000 and 4000 not in steps
    assert [i for i in range(6000) if INDOOR.is_prune_step(i)] == [3500, 4000, 4500, 5000, 5500]
    assert [i for i in range(30001) if FULL.is_hard_prune_step(i)] == [5000]
    t = FULL.prune_threshold
    assert t(0) == t(4999) == t(5000) == t(5499) == pytest.approx(0.235)
    assert t(5500) == pytest.approx(0.245) and t(6000) == pytest.approx(0.255) and t(6499) == pytest.approx(0.255)
    assert FULL.prune_max_size() == 1400 and INDOOR.prune_max_size() == 1300


def test_densification():
    steps = [i for i in range(30001) if FULL.is_densify_step(i)]
    assert steps == list(range(1000, 13000, 500))
    steps = [i for i in range(30001) if INDOOR.is_densify_step(i)]
    assert steps == list(range(1500, 25000, 500))
    assert FULL.densify_count(1000) == 230 and INDOOR.densify_count(1000) == 270
    assert FULL.densify_count(0) == 0
    assert FULL.densify_count(2_900_000) == 100_000           # capped
    assert FULL.densify_count(3_000_000) == 0 and FULL.densify_count(3_500_000) == 0   # never negative
    assert FULL.densify_count(1000, cap=1100) == 100
    assert FULL.densify_always_largest() == 100 and INDOOR.densify_always_largest() == 500
    with pytest.raises(ValueError):
        FULL.densify_count(-1)


def test_supersample_and_losses():
    s = FULL.supersample
    assert [s(i) for i in (0, 19999, 20000, 24999, 25000, 30000)] == [1, 1, 2, 2, 4, 4]
    assert FULL.opacity_reg_weight(4999) == 1.9e-6 and FULL.opacity_reg_weight(5000) == 0.0
    assert FULL.normal_loss_weight(5000) == 0.0 and FULL.normal_loss_weight(5001) == 0.05
    assert INDOOR.normal_loss_weight(5001) == 0.025


def test_quick_scaling():
    q = Schedule(total=3000, quick=True)
    assert q.position_lr(99) == 0.0 and q.position_lr(100) > 0
    assert q.position_lr(3000) == pytest.approx(0.0015 / 100)
    assert [q.sh_degree(i) for i in (99, 100, 200, 300, 3000)] == [0, 1, 2, 3, 3]
    assert q.opacity_floor(499) == 0 and q.opacity_floor(500) == pytest.approx(0.1)
    assert q.opacity_floor(2400) == pytest.approx(0.9999)
    assert [i for i in range(3001) if q.opacity_floor_changes(i)] == list(range(500, 2401, 50))
    assert [i for i in range(3001) if q.is_densify_step(i)] == list(range(100, 1300, 50))
    assert [i for i in range(3001) if q.is_hard_prune_step(i)] == [500]
    assert [q.supersample(i) for i in (1999, 2000, 2500)] == [1, 2, 4]
    assert q.prune_threshold(550) == pytest.approx(0.245)
    # same schedule at full scale whether quick or not
    full_q = Schedule(total=30000, quick=True)
    for i in range(0, 30001, 250):
        assert full_q.state(i) == FULL.state(i)
    # tiny runs: intervals stay >= 1, nothing divides by zero
    tiny = Schedule(total=7, quick=True)
    for i in range(8):
        tiny.state(i)
    # unscaled short run keeps the 30k constants
    assert Schedule(total=3000).sh_degree(2999) == 2


def test_bad_inputs():
    with pytest.raises(ValueError):
        Schedule(total=0)
    with pytest.raises(ValueError):
        FULL.sigma(-1)
    with pytest.raises(ValueError):
        FULL.sigma(1.5)


def test_quick_topology_interval_and_opacity_lr():
    # 300 quick iterations, 7 training views, at least 3 epochs between topology events
    q = Schedule(total=300, quick=True, views=7, topology_epochs=3, opacity_lr_scale=10)
    assert q.topology_every() == 21
    prunes = [i for i in range(301) if q.is_prune_step(i)]
    assert prunes[0] == 40 + 21 and all(b - a == 21 for a, b in zip(prunes, prunes[1:]))
    dens = [i for i in range(301) if q.is_densify_step(i)]
    assert dens == list(range(5 + 21, 130, 21))
    assert [i for i in range(301) if q.is_hard_prune_step(i)] == [61]     # the first prune at or after 50
    assert q.prune_threshold(61) == pytest.approx(0.235) and q.prune_threshold(82) == pytest.approx(0.245)
    assert q.opacity_lr() == pytest.approx(0.3)
    # the paper preset (not quick) ignores both knobs
    p = Schedule(views=7, topology_epochs=3, opacity_lr_scale=10)
    for i in range(0, 30001, 250):
        assert p.state(i) == FULL.state(i)
    # a short interval stays the scaled 500 when an epoch is shorter
    assert Schedule(total=3000, quick=True, views=7, topology_epochs=3).topology_every() == 50


def test_floor_starts_at_the_hard_prune_in_stretched_quick_runs():
    """With whole-epoch topology intervals the hard prune comes after the scaled 5000; the floor
    must not rise before it, or the prune's opacity test (thr 0.235) can remove nothing."""
    s = Schedule(total=1500, quick=True, views=100, topology_epochs=3)
    hard = [i for i in range(1, 1501) if s.is_hard_prune_step(i)]
    assert hard == [s.floor_start()] and hard[0] > s.at(5000)
    assert s.opacity_floor(hard[0] - 1) == 0.0 and s.opacity_floor(hard[0]) == pytest.approx(0.1)
    assert s.opacity_floor(hard[0]) < s.prune_threshold(hard[0])
    assert s.opacity_floor(s.at(24000)) == pytest.approx(0.9999)
    # unchanged where the interval is the scaled 500, and in the paper's run
    q = Schedule(total=3000, quick=True)
    assert q.floor_start() == q.at(5000) == 500
    assert Schedule().floor_start() == 5000



def test_floor_still_ends_opaque_when_the_run_is_too_short_for_a_hard_prune():
    for total in (2, 6, 12, 16, 40):
        s = Schedule(total=total, quick=True, views=21, topology_epochs=3)
        assert s.opacity_floor(total) == pytest.approx(0.9999), total


@pytest.mark.parametrize("total", [1, 30, 600, 2200, 3000, 30000])
@pytest.mark.parametrize("quick", [True, False])
def test_first_prune_step_is_the_first_iteration_that_prunes(total, quick):
    s = Schedule(total=total, quick=quick)
    assert s.first_prune_step() == next((i for i in range(1, total + 1) if s.is_prune_step(i)), None)


@pytest.mark.parametrize("total,views", [(600, 21), (1700, 67), (2900, 24), (300, 1)])
def test_the_early_prune_comes_at_the_densify_steps_before_the_first_prune(total, views):
    s = Schedule(total=total, quick=True, views=views, topology_epochs=3, early_prune=True)
    first = s.first_prune_step()
    early = [i for i in range(1, total + 1) if s.is_early_prune_step(i)]
    assert early == [i for i in range(1, (first or total + 1)) if s.is_densify_step(i)]
    assert early and not any(s.is_prune_step(i) for i in early)
    assert all(s.state(i)["early_prune"] == (i in early) for i in range(1, total + 1))
    # only a quick run with the switch and the opacity criterion on
    for off in (dict(early_prune=False), dict(hard_prune=False), dict(quick=False)):
        o = Schedule(**{**dict(total=total, quick=True, views=views, topology_epochs=3, early_prune=True), **off})
        assert not any(o.is_early_prune_step(i) for i in range(1, total + 1)), off
