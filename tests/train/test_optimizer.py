"""The trainer's optimiser step (tsplus_wgpu.train.optimizer): the positions' step by depth."""

import numpy as np

import tsplus_wgpu.reference.optim as twin
from tsplus_wgpu.train.trainer import TrainConfig, Trainer


def _first_moving_step(t):
    it = 1
    while t.sched.learning_rates(it)["positions"] == 0:
        it += 1
    return it


def test_the_position_step_is_scaled_by_depth(renderer):
    """Up to the first step with a position learning rate, runs with and without the scale are
    the same (Adam's moments do not depend on the rate). That step moves each vertex by the
    unscaled run's step times min(1, distance to the nearest training camera), read from the
    positions before it (the twin); vertices near the cameras move less, far ones the same."""
    from tsplus_wgpu.data.procedural import load_procedural
    tiny = load_procedural("tiny")
    runs = {}
    for on in (False, True):
        t = Trainer(tiny, TrainConfig(iterations=24, quick=True, topology=False, log_every=0, position_lr_depth=on),
                    renderer=renderer)
        first = _first_moving_step(t)
        t.train(progress=False, until=first - 1, checkpoint_at_end=False)
        before = t.positions_frame().astype(np.float64)
        t.step()
        runs[on] = (before, t.positions_frame().astype(np.float64) - before)
        centres = np.array([t.scene.cameras[v].center for v in t.train_views])
    np.testing.assert_array_equal(runs[False][0], runs[True][0])
    scale = twin.depth_scale(runs[True][0], centres)
    assert scale.min() < 0.9 and (scale == 1).any()             # both kinds of vertex in the tiny scene
    moved = np.abs(runs[False][1]).max(axis=1) > 0
    np.testing.assert_allclose(runs[True][1][moved], runs[False][1][moved] * scale[moved, None], rtol=1e-3, atol=1e-9)
