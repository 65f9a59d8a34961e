"""What ``tsplus bench`` runs on each scene: the per-scene plans (iterations, evaluation
points, budgets, ablations), the default scene list and the command line's overrides."""

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

@dataclass
class ScenePlan:
    """What the bench runs on one scene (``tsplus bench --help`` lists the defaults)."""

    name: str
    scene: str
    downscale: int = 1
    iterations: int = 300            # the quick run and every ablation / budget run
    long_factor: int = 3             # the longer run: iterations x long_factor
    eval_points: int = 5             # evaluations along each curve, iteration 0 included
    test_views: int = 25             # at most this many held-out views, evenly spaced
    topology_epochs: float = 1.0     # quick_topology_epochs of the runs with topology on
    budgets: tuple = (0.0, 0.25, 0.5)  # --max-vertices = V0 + f (peak - V0) of the no-stop run (V0: initial)
    profile_every: int = 10
    blend_repeats: int = 5
    peak_repeats: int = 5
    poisson_depth: int = 9
    long: bool = True
    ablations: tuple = ()            # ablation names (default: all)
    budget_runs: bool = True
    poisson: bool = True
    minutes: float = 0.0             # the stated time of this plan on lavapipe (2 cores), for --help

    def planned_iterations(self):
        """Training iterations of every run of this plan (the overall progress bar's total)."""
        n = int(self.iterations)
        total = n + n * len(self.ablations)
        if self.long and self.long_factor > 1:
            total += n * int(self.long_factor)
        if self.budget_runs:
            total += n * (1 + len(self.budgets))
        return total


def data_dir():
    """``TSPLUS_DATA``, else ``shared/data`` beside the checkout, else ``../shared/data``."""
    env = os.environ.get("TSPLUS_DATA")
    if env:
        return Path(env)
    beside = Path(__file__).resolve().parents[3] / "shared" / "data"
    return beside if beside.is_dir() else Path("../shared/data")


#: per-scene defaults (scene folder name -> plan); other folders get GENERIC with downscale 4
DEFAULT_PLANS = {
    "procedural": dict(scene="procedural:small", downscale=1, iterations=300, long_factor=3, minutes=12),
    "cup": dict(downscale=8, iterations=240, long_factor=2, minutes=14),
    "chair": dict(downscale=4, iterations=300, long_factor=3, minutes=5),
    "fox": dict(downscale=12, iterations=300, long_factor=2, minutes=8),
}
GENERIC = dict(downscale=4, iterations=300, long_factor=2, minutes=0)

SMOKE_PLAN = dict(name="procedural-tiny", scene="procedural:tiny", iterations=16, long_factor=2, eval_points=3,
                  test_views=2, topology_epochs=1.0, budgets=(0.5,), profile_every=4, blend_repeats=2,
                  peak_repeats=3, poisson_depth=6, ablations=("baseline", "no-hard-prune", "no-weight-prune",
                                                                "no-sigma-decay", "soft-opaque", "hard-free",
                                                                "soft-free"), minutes=1)


def default_scenes():
    """The procedural scene, then every scene folder in :func:`data_dir` (sorted)."""
    out = ["procedural"]
    d = data_dir()
    if d.is_dir():
        out += sorted(str(p) for p in d.iterdir() if p.is_dir() and not p.name.startswith("."))
    return out


def plan_for(spec, args=None):
    """A :class:`ScenePlan` for a scene argument (``procedural[:size]``, a folder, or the name of
    a folder in ``TSPLUS_DATA``), with the command line's overrides."""
    from ..train.ablations import ABLATIONS
    smoke = bool(getattr(args, "smoke", False))
    if smoke and spec in ("procedural", "procedural:tiny"):
        plan = ScenePlan(**SMOKE_PLAN)
    elif spec.startswith("procedural"):
        kw = dict(DEFAULT_PLANS["procedural"])
        if ":" in spec:
            kw["scene"] = spec
        size = kw["scene"].split(":", 1)[1]
        plan = ScenePlan(name="procedural" if size == "small" else f"procedural-{size}", **kw)
    else:
        path = Path(spec)
        if not path.exists() and (data_dir() / spec).exists():
            path = data_dir() / spec
        kw = dict(DEFAULT_PLANS.get(path.name, GENERIC))
        plan = ScenePlan(name=path.name or str(path), scene=str(path), **kw)
    if not plan.ablations:
        plan = replace(plan, ablations=tuple(ABLATIONS))
    if args is not None:
        plan = replace(plan, **_overrides(plan, args))
    return plan


def _overrides(plan, args):
    """The ScenePlan fields the command line ``args`` sets (argparse names)."""
    over = {}
    for key in ("iterations", "long_factor", "eval_points", "test_views", "profile_every", "topology_epochs"):
        val = getattr(args, key, None)
        if val is not None:
            over[key] = val
    if getattr(args, "downscale", None) is not None and not plan.scene.startswith("procedural"):
        over["downscale"] = args.downscale
    if getattr(args, "budgets", None) is not None:
        over["budgets"] = tuple(args.budgets)
    if getattr(args, "no_long", False):
        over["long"] = False
    if getattr(args, "no_ablations", False):
        over["ablations"] = ("baseline",)
    if getattr(args, "no_budgets", False):
        over["budget_runs"] = False
    if getattr(args, "no_poisson", False):
        over["poisson"] = False
    return over


def eval_views(scene, k):
    """At most ``k`` held-out views of ``scene``, evenly spaced (its training views when it has none)."""
    views = list(scene.test_indices) or list(scene.train_indices)
    if k and len(views) > k:
        idx = np.unique(np.round(np.linspace(0, len(views) - 1, int(k))).astype(int))
        views = [views[i] for i in idx]
    return views


def curve_iterations(total, points):
    """``points`` iterations from 0 to ``total``, evenly spaced: where a curve is evaluated."""
    points = max(2, int(points))
    return sorted({int(round(total * i / (points - 1))) for i in range(points)})


__all__ = ["ScenePlan", "DEFAULT_PLANS", "GENERIC", "SMOKE_PLAN", "data_dir", "default_scenes", "plan_for",
           "eval_views", "curve_iterations"]
