"""Every training schedule of Triangle Splatting+ (``method.md``) as pure functions of the
iteration and the run length.

Iterations are counted as in the authors' trainer: the first optimisation step is
iteration 1, the last is ``total``; iteration 0 is the initial state.

The constants are the ones of the 30k-iteration run. With ``quick=True`` every iteration
constant (starts, ends, intervals) is scaled by ``total / 30000`` (rounded, intervals at
least 1), so a short run goes through the same phases in the same proportions. Periodic
events happen at ``start + k * interval`` (k >= 0 or >= 1 as stated per function); at full
scale that is the same as "every multiple of 500", since every start is a multiple of 500.
Schedules that are already expressed over the run (position learning-rate decay, sigma)
use ``total`` directly and need no scaling.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

FULL_RUN = 30000

# Learning rates
POSITION_LR_INIT = 0.0015
POSITION_LR_FINAL = 0.0015 / 100
POSITION_LR_START = 1000          # positions are frozen (lr 0) before this iteration
SH_DC_LR = (0.0016, 0.004)        # (outdoor, indoor)
SH_REST_DIVISOR = 20.0
OPACITY_LR = (0.03, 0.05)
ADAM_EPS = 1e-15

# SH degree
SH_DEGREE_EVERY = 1000
SH_DEGREE_MAX = 3

# Window sharpness
SIGMA_INIT = 1.0
SIGMA_FINAL = 0.0001

# Opacity floor m
FLOOR_START = 5000
FLOOR_EVERY = 500
FLOOR_RAMP_END = 24000
FLOOR_MIN = 0.1
FLOOR_MAX = 0.9999
INIT_OPACITY = 0.28

# Pruning
PRUNE_AFTER = (4000, 3000)        # prune at PRUNE_AFTER + k * PRUNE_EVERY, k >= 1
PRUNE_EVERY = 500
HARD_PRUNE_AT = 5000
PRUNE_THRESHOLD = 0.235
PRUNE_THRESHOLD_STEP = 0.01       # added every PRUNE_EVERY iterations after HARD_PRUNE_AT
PRUNE_MAX_SIZE_PX = (1400.0, 1300.0)
FINAL_PRUNE_WEIGHT = 0.5

# Densification
DENSIFY_WINDOW = ((500, 13000), (1000, 25000))  # exclusive bounds, (outdoor, indoor)
DENSIFY_EVERY = 500
DENSIFY_GROWTH = (1.23, 1.27)
DENSIFY_CAP = 3_000_000
DENSIFY_ALWAYS_LARGEST = (100, 500)
DENSIFY_MIN_AREA = 7.5e-5

# Losses
OPACITY_REG_WEIGHT = 1.9e-6
OPACITY_REG_UNTIL = 5000          # applied while it < this
NORMAL_LOSS_AFTER = 5000          # applied while it > this
NORMAL_LOSS_WEIGHT = (0.05, 0.025)

# Anti-aliasing (render at s x resolution, area-downsample)
SUPERSAMPLE_STEPS = ((20000, 2), (25000, 4))
SUPERSAMPLE_EVAL = 4

# Ablations (the paper's Tables 2-3)
SIGMA_SOFT = 0.1                  # "soft denotes 0.1"
OPACITY_MODES = ("opaque", "free")


def _check_it(it):
    if isinstance(it, bool) or int(it) != it or it < 0:
        raise ValueError(f"iteration: expected an integer >= 0, got {it!r}")
    return int(it)


@dataclass(frozen=True)
class Schedule:
    """All schedules of one run.

    Args:
        total: number of iterations of the run (>= 1).
        indoor: use the indoor constants (the bracketed values of method.md).
        quick: scale every iteration constant by ``total / 30000`` (for short runs).
        sigma_final, sigma_decay, opacity_mode, hard_prune, weight_prune: the switches of
            the paper's ablations (Tables 2-3), defaults = the method:

            * ``sigma_final``: sigma at the end of the decay (0.0001 hard; the paper's "soft"
              is 0.1).
            * ``sigma_decay=False``: sigma is ``sigma_final`` from the first iteration (solid
              triangles from the start; "w/o sigma decay").
            * ``opacity_mode``: ``"opaque"`` (the floor ramps to 0.9999) or ``"free"`` (the
              floor stays 0: opacity is optimised freely to the end; the exported mesh still
              drops it).
            * ``hard_prune=False``: no opacity criterion in any prune ("w/o hard pruning step").
              The paper's hard pruning step *is* the opacity test (min vertex opacity <= T_o);
              method.md, like the authors' code, applies it at every prune step, so dropping
              it only at 5000 would change nothing (4500 and 5500 run the same test at
              thresholds 0.235 / 0.245): the switch removes the criterion itself.
            * ``weight_prune=False``: no max-blending-weight criterion (opacity and size only:
              "w/o blending weight pruning").
        early_prune: with ``quick``, the densify steps before the first prune step also prune by
            opacity (:meth:`is_early_prune_step`; ``TrainConfig.quick_early_prune``).
    """

    total: int = FULL_RUN
    indoor: bool = False
    quick: bool = False
    views: int = 1
    topology_epochs: float = 0.0
    opacity_lr_scale: float = 1.0
    sigma_final: float = SIGMA_FINAL
    sigma_decay: bool = True
    opacity_mode: str = "opaque"
    hard_prune: bool = True
    weight_prune: bool = True
    early_prune: bool = False

    def __post_init__(self):
        if isinstance(self.total, bool) or int(self.total) != self.total or self.total < 1:
            raise ValueError(f"total: expected an integer >= 1, got {self.total!r}")
        if not (isinstance(self.sigma_final, (int, float)) and 0.0 < float(self.sigma_final) <= SIGMA_INIT):
            raise ValueError(f"sigma_final: expected a number in (0, {SIGMA_INIT}], got {self.sigma_final!r}")
        if self.opacity_mode not in OPACITY_MODES:
            raise ValueError(f"opacity: expected one of {', '.join(OPACITY_MODES)}, got {self.opacity_mode!r}")

    # ------------------------------------------------------------------ scaling
    def at(self, iteration_at_30k):
        """An iteration constant of the 30k run in this run's units (scaled when quick)."""
        if not self.quick:
            return int(iteration_at_30k)
        return int(round(iteration_at_30k * self.total / FULL_RUN))

    def every(self, interval_at_30k):
        """An interval of the 30k run in this run's units (>= 1)."""
        return max(1, self.at(interval_at_30k))

    def topology_every(self):
        """The interval between topology events (prune, densify): 500 scaled, and in a quick
        run at least ``topology_epochs`` epochs of ``views`` training views."""
        base = self.every(PRUNE_EVERY)
        if self.quick and self.topology_epochs > 0:
            base = max(base, int(math.ceil(self.topology_epochs * max(1, int(self.views)))))
        return base

    def _pick(self, pair):
        return pair[1] if self.indoor else pair[0]

    # ------------------------------------------------------------------ learning rates
    def position_lr(self, it, scale=1.0):
        """0 before iteration 1000; from then log-linear from 0.0015 at iteration 0 to
        0.0015/100 at the last iteration (the decay runs over the whole run, as in 3DGS's
        exponential schedule; the first 1000 iterations are masked to 0). ``scale`` multiplies
        the rate (e.g. a scene-extent factor; method.md uses none)."""
        it = _check_it(it)
        if it < self.at(POSITION_LR_START):
            return 0.0
        t = min(max(it / self.total, 0.0), 1.0)
        return scale * math.exp(math.log(POSITION_LR_INIT) * (1.0 - t) + math.log(POSITION_LR_FINAL) * t)

    def sh_dc_lr(self, it=0):
        return self._pick(SH_DC_LR)

    def sh_rest_lr(self, it=0):
        return self._pick(SH_DC_LR) / SH_REST_DIVISOR

    def opacity_lr(self, it=0):
        return self._pick(OPACITY_LR) * (self.opacity_lr_scale if self.quick else 1.0)

    def learning_rates(self, it, position_scale=1.0):
        return {"positions": self.position_lr(it, position_scale), "sh_dc": self.sh_dc_lr(it),
                "sh_rest": self.sh_rest_lr(it), "opacity": self.opacity_lr(it)}

    # ------------------------------------------------------------------ SH degree, sigma
    def sh_degree(self, it):
        """+1 every 1000 iterations, up to 3: 0 for it < 1000, 1 for it < 2000, ..."""
        it = _check_it(it)
        return min(SH_DEGREE_MAX, it // self.every(SH_DEGREE_EVERY))

    def sigma(self, it):
        """Linear from 1.0 at iteration 0 to ``sigma_final`` (0.0001) at the last iteration
        (held after); ``sigma_final`` throughout without ``sigma_decay``."""
        t = min(_check_it(it) / self.total, 1.0)
        if not self.sigma_decay:
            return float(self.sigma_final)
        return SIGMA_INIT + (float(self.sigma_final) - SIGMA_INIT) * t

    # ------------------------------------------------------------------ opacity floor
    def opacity_floor(self, it):
        """m: 0 before iteration 5000 (:meth:`floor_start`); at 5000 + k*500 (k >= 0) it becomes
        ``0.1 + (0.9999 - 0.1) * clamp((it - 5000) / (24000 - 5000), 0, 1)`` and holds until the
        next update. Always 0 with ``opacity_mode="free"``."""
        it = _check_it(it)
        if self.opacity_mode == "free":
            return 0.0
        start, every, end = self.floor_start(), self.every(FLOOR_EVERY), self.at(FLOOR_RAMP_END)
        if it < start:
            return 0.0
        last = start + (it - start) // every * every    # the last update at or before it
        span = max(end - start, 1)
        frac = min(max((last - start) / span, 0.0), 1.0)
        return FLOOR_MIN + (FLOOR_MAX - FLOOR_MIN) * frac

    def floor_start(self):
        """The iteration the floor first rises (to 0.1): 5000, the hard prune's iteration, as in
        method.md. In a quick run whose topology interval is stretched to whole epochs
        (``topology_epochs``) the hard prune comes at the first prune step at or after the scaled
        5000; the floor then starts there too. Otherwise the floor would already be above the
        prune threshold at the hard prune, whose opacity test could then remove nothing (chair,
        100 views, 1500 quick iterations: hard prune at 500 with the floor at 0.34 > 0.235, 0
        triangles pruned by opacity, and opaque floaters in front of the cameras stay)."""
        at = self.at(FLOOR_START)
        if not self.quick or self.topology_every() == self.every(PRUNE_EVERY):
            return at
        after, every = self.at(self._pick(PRUNE_AFTER)), self.topology_every()
        k = max(1, -(-(at - after) // every))
        hard = max(at, after + k * every)
        # a hard prune at or after the ramp's end (runs too short for one) protects nothing:
        # the floor then keeps method.md's start, so the run still ends opaque
        return hard if hard < self.at(FLOOR_RAMP_END) else at

    def opacity_floor_changes(self, it):
        """True when the floor takes a new value at this iteration (re-invert the logits then)."""
        return it >= 1 and self.opacity_floor(it) != self.opacity_floor(it - 1)

    # ------------------------------------------------------------------ pruning
    def is_prune_step(self, it):
        """Every 500 iterations after 4000 [3000] (4500, 5000, ...)."""
        it = _check_it(it)
        after, every = self.at(self._pick(PRUNE_AFTER)), self.topology_every()
        return it > after and (it - after) % every == 0

    def first_prune_step(self):
        """The first iteration :meth:`is_prune_step` holds for (None: the run ends before it)."""
        first = self.at(self._pick(PRUNE_AFTER)) + self.topology_every()
        return first if first <= self.total else None

    def is_early_prune_step(self, it):
        """A quick run's opacity prune before its first prune step (``early_prune``, with the
        opacity criterion on): every densify step before :meth:`first_prune_step` also deletes the
        triangles whose min vertex opacity is at or below :meth:`prune_threshold` (not a method.md
        step: the quick schedule's first prune comes after 3 epochs, and until then each
        iteration draws the whole initial Delaunay mesh, most of whose faces the early opacity
        loss has already made transparent)."""
        if not (self.quick and self.early_prune and self.hard_prune) or not self.is_densify_step(it):
            return False
        first = self.first_prune_step()
        return first is None or it < first

    def is_hard_prune_step(self, it):
        """The hard prune of the paper (iteration 5000; in a quick run with a longer topology
        interval, the first prune step at or after it)."""
        it = _check_it(it)
        at = self.at(HARD_PRUNE_AT)
        if self.topology_every() == self.every(PRUNE_EVERY):
            return it == at
        return it >= at and self.is_prune_step(it) and not any(self.is_prune_step(j) for j in range(at, it))

    def prune_criteria(self):
        """The tests a prune step applies: ``opacity`` (min vertex opacity <= thr; the hard
        prune, off with ``hard_prune=False``), ``weight`` (max blending weight over the training
        views <= thr; off with ``weight_prune=False``), ``size`` (projected size > 1400 px)."""
        return tuple(name for name, on in (("opacity", self.hard_prune), ("weight", self.weight_prune),
                                           ("size", True)) if on)

    def prune_threshold(self, it):
        """0.235, plus 0.01 for every 500 iterations completed after 5000."""
        it = _check_it(it)
        start, every = self.at(HARD_PRUNE_AT), self.topology_every()
        steps = max(0, (it - start) // every) if it >= start else 0
        return PRUNE_THRESHOLD + PRUNE_THRESHOLD_STEP * steps

    def prune_max_size(self):
        """Projected size (px) above which a triangle is pruned: method.md's 1400 [1300] px at
        any image size. (Scaling it with the image diagonal was tried: at 160x120 it pruned
        29,053 triangles near the cameras of the procedural room in one step, 8,680 unscaled,
        and tripled the quick-start run's mean training L1 over iterations 900-1075; not
        adopted.)"""
        return self._pick(PRUNE_MAX_SIZE_PX)

    # ------------------------------------------------------------------ densification
    def is_densify_step(self, it):
        """Every 500 iterations strictly inside (500, 13000) [(1000, 25000)]."""
        it = _check_it(it)
        lo, hi = (self.at(x) for x in self._pick(DENSIFY_WINDOW))
        every = self.topology_every()
        return lo < it < hi and (it - lo) % every == 0

    def densify_count(self, num_vertices, cap=DENSIFY_CAP):
        """Triangles to split: ``n = min(cap, growth * V) - V`` (growth 1.23 [1.27]), rounded
        down and never negative."""
        v = int(num_vertices)
        if v < 0:
            raise ValueError(f"num_vertices: expected >= 0, got {num_vertices!r}")
        target = min(float(cap), self._pick(DENSIFY_GROWTH) * v)
        return max(0, int(math.floor(target)) - v)

    def densify_always_largest(self):
        return self._pick(DENSIFY_ALWAYS_LARGEST)

    # ------------------------------------------------------------------ losses, supersampling
    def opacity_reg_weight(self, it):
        return OPACITY_REG_WEIGHT if _check_it(it) < self.at(OPACITY_REG_UNTIL) else 0.0

    def normal_loss_weight(self, it):
        return self._pick(NORMAL_LOSS_WEIGHT) if _check_it(it) > self.at(NORMAL_LOSS_AFTER) else 0.0

    def supersample(self, it):
        """Render at s x resolution: 1, 2 from iteration 20000, 4 from 25000."""
        it = _check_it(it)
        s = 1
        for start, factor in SUPERSAMPLE_STEPS:
            if it >= self.at(start):
                s = factor
        return s

    def state(self, it):
        """Every schedule at one iteration, as a dict."""
        return dict(iteration=int(it), sh_degree=self.sh_degree(it), sigma=self.sigma(it),
                    opacity_floor=self.opacity_floor(it), floor_changes=self.opacity_floor_changes(it),
                    prune=self.is_prune_step(it), hard_prune=self.is_hard_prune_step(it),
                    early_prune=self.is_early_prune_step(it),
                    prune_criteria=self.prune_criteria(),
                    prune_threshold=self.prune_threshold(it), densify=self.is_densify_step(it),
                    supersample=self.supersample(it), **{f"lr_{k}": v for k, v in self.learning_rates(it).items()})


# ---------------------------------------------------------------------- opacity mapping

def sigmoid(w):
    w = np.asarray(w, np.float64)
    return np.where(w >= 0, 1.0 / (1.0 + np.exp(-np.abs(w))), np.exp(-np.abs(w)) / (1.0 + np.exp(-np.abs(w))))


def opacity_from_logit(w, m):
    """o = m + (1 - m) * sigmoid(w)."""
    return m + (1.0 - m) * sigmoid(w)


def logit_from_opacity(o, m, eps=1e-6):
    """Inverse of :func:`opacity_from_logit`. Opacities at or below the floor (or at 1) have no
    finite logit: ``(o - m) / (1 - m)`` is clamped to ``[eps, 1 - eps]`` first, so they come
    back just above the floor (or just below 1)."""
    if not 0.0 <= m < 1.0:
        raise ValueError(f"opacity floor m must be in [0, 1), got {m!r}")
    q = (np.asarray(o, np.float64) - m) / (1.0 - m)
    q = np.clip(q, eps, 1.0 - eps)
    return np.log(q) - np.log1p(-q)


def reinvert_logits(w, m_old, m_new, eps=1e-6):
    """New logits that keep each vertex's opacity when the floor goes from ``m_old`` to
    ``m_new``: ``m_new + (1 - m_new) sigmoid(w_new) = m_old + (1 - m_old) sigmoid(w)``.
    Vertices below the new floor end just above it (see :func:`logit_from_opacity`)."""
    return logit_from_opacity(opacity_from_logit(w, m_old), m_new, eps)
