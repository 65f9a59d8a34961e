"""Pruning and densification of Triangle Splatting+ (method.md) as a strategy object with
pre/post-step hooks, apart from the rasterizer: :class:`TopologyStrategy`.

Per step (``post_step``, on the device, no readback): the forward pass's per-triangle max
blending weight is folded into a running maximum (``max_weight_accumulate.wgsl``, twin
:func:`max_weight_accumulate_reference`), and the step's training L1 is copied into a ring
buffer (for the densification stop).

At a topology step (every 500 iterations, scaled with ``quick``; one host round trip):

1. **Prune** (``Schedule.is_prune_step``: every 500 after 4000 [3000]; the criteria of
   ``Schedule.prune_criteria``, all three unless an ablation switches one off): delete triangles whose
   min vertex opacity <= thr, whose max blending weight over the training views <= thr, or
   whose projected size (max vertex-to-centroid distance, px, max over the training views in
   front of the near plane) > 1400 [1300]; thr = ``Schedule.prune_threshold``. The **hard
   prune** (``is_hard_prune_step``, 5000) is the opacity criterion (the paper's "remove all
   triangles with opacity below T_o"); it is also part of every regular prune, so at 5000 the
   two coincide. The weight criterion needs the maximum over *all* training views: when the
   views rendered since the last reset do not cover them (a quick run's interval is shorter
   than an epoch), that prune skips the weight criterion and the maximum keeps accumulating;
   the maximum is reset after each prune that applied it.
2. **Remove unused vertices** and compact the indices (:func:`remove_unused_vertices`).
3. **Densify** (``is_densify_step``: every 500 in (500, 13000) [(1000, 25000)]) unless
   stopped: ``n = min(cap, 1.23 [1.27] V) - V`` (``Schedule.densify_count``, cap =
   ``max_vertices``, n <= 0: nothing) triangles drawn without replacement with probability
   proportional to the max blending weight (0 where the 3D area < 7.5e-5; at most as many as
   have a non-zero probability, so all-zero weights draw none), plus the 100 [500] largest by
   area (:func:`choose_split`). Each becomes 4 (:func:`subdivide`); a midpoint vertex is keyed
   by its edge, so two chosen neighbours share it; it gets the mean position, SH and
   activated opacity of the edge's two vertices; parents are removed. The chosen list is cut
   (largest last) so that V never exceeds ``max_vertices``. Children inherit their parent's
   running max weight (only matters before the first weight prune resets it).

**Adam state follows every edit**: rows of surviving vertices are kept (moved with the index
compaction); a midpoint vertex gets the *mean* of its edge's two vertices' first and second
moments (its parameters are that mean too, so its first step is as large as its parents'
rather than the ~3x larger step a zero second moment gives).

**Densification stop** ("model only what the scene needs"): at each topology step the mean
training L1 of the iterations since the previous topology step is appended to a history; at
each densify step, with S_now the mean of the last K windows and S_prev the mean of the K before (K =
``densify_stop_windows``, 3), densification stops for good when
``(S_prev - S_now) / S_prev < densify_stop_rel`` (0.01; 0 disables), or when V reached
``max_vertices``. The reason is logged (``event: densify_stop``). Windows that
straddle a prune count like any other: a prune raises the training L1 for a while, and the stop
then reads it as "no better". That is deliberate, measured on procedural:small, quick, 3000
iterations: the stop fires at iteration 554, just after the hard prune (78,697 vertices; held-out
mesh 25.56 dB); starting the history over at the hard prune instead kept densifying to 240,209
vertices by iteration 725 with no lower training L1 (0.0315 -> 0.0339) at a fifth of the speed.

Sampling uses ``numpy.random.default_rng([seed, iteration, 1])``: stateless, so a resumed run
draws what an uninterrupted one draws.
"""

from __future__ import annotations

import math

import numpy as np

from ..gpu import Stage
from .schedules import DENSIFY_MIN_AREA, logit_from_opacity, opacity_from_logit

# ---------------------------------------------------------------------- pure mesh edits


def max_weight_accumulate_reference(acc, weights, reset=False):
    w = np.asarray(weights, np.float32)
    return w.copy() if reset else np.maximum(np.asarray(acc, np.float32), w)


def triangle_areas(positions, triangles):
    """3D area of each triangle ``[M]``."""
    p = np.asarray(positions, np.float64)
    t = np.asarray(triangles, np.int64)
    if len(t) == 0:
        return np.zeros(0)
    return 0.5 * np.linalg.norm(np.cross(p[t[:, 1]] - p[t[:, 0]], p[t[:, 2]] - p[t[:, 0]]), axis=1)


def projected_sizes(positions, triangles, cameras, near=0.01):
    """Max over ``cameras`` of the projected size (max vertex-to-centroid distance, px) of each
    triangle; views where a vertex is at camera z <= near do not count. ``[M]``."""
    p = np.asarray(positions, np.float64)
    t = np.asarray(triangles, np.int64)
    out = np.zeros(len(t))
    for cam in cameras:
        w2c = np.asarray(cam.world_to_camera, np.float64)
        x = p @ w2c[:3, :3].T + w2c[:3, 3]
        z = x[:, 2]
        zs = np.where(z > near, z, 1.0)
        uv = np.stack([cam.fx * x[:, 0] / zs + cam.cx, cam.fy * x[:, 1] / zs + cam.cy], axis=1)
        tri_uv = uv[t]                                            # [M, 3, 2]
        c = tri_uv.mean(axis=1, keepdims=True)
        size = np.linalg.norm(tri_uv - c, axis=2).max(axis=1)
        ok = (z[t] > near).all(axis=1)
        out = np.where(ok, np.maximum(out, size), out)
    return out


def remove_unused_vertices(triangles, num_vertices):
    """Returns ``(triangles with compacted indices, old_from_new [V'])``; vertex order kept."""
    t = np.asarray(triangles, np.int64).reshape(-1, 3)
    used = np.zeros(int(num_vertices), bool)
    used[t.ravel()] = True
    new_from_old = np.cumsum(used) - 1
    return new_from_old[t], np.flatnonzero(used)


def choose_split(weights, areas, n, largest, rng, min_area=DENSIFY_MIN_AREA):
    """Triangles to split: ``n`` drawn without replacement with probability proportional to
    ``weights`` (0 where ``areas < min_area``; never more than have a non-zero probability),
    then the ``largest`` by area not drawn already. Nothing when ``n <= 0``. Returns indices
    in that order (int64)."""
    n = int(n)
    m = len(weights)
    if n <= 0 or m == 0:
        return np.zeros(0, np.int64)
    p = np.where(np.asarray(areas) >= min_area, np.maximum(np.asarray(weights, np.float64), 0.0), 0.0)
    p = np.where(np.isfinite(p), p, 0.0)
    k = min(n, int(np.count_nonzero(p)))
    drawn = rng.choice(m, size=k, replace=False, p=p / p.sum()) if k > 0 else np.zeros(0, np.int64)
    big = np.argsort(-np.asarray(areas, np.float64), kind="stable")[:int(largest)]
    big = big[~np.isin(big, drawn)]
    return np.concatenate([drawn, big]).astype(np.int64)


def _edge_keys(triangles, chosen, num_vertices):
    t = np.asarray(triangles, np.int64)[chosen]                       # [C, 3]
    a, b, c = t[:, 0], t[:, 1], t[:, 2]
    e0 = np.stack([np.stack([a, b], 1), np.stack([b, c], 1), np.stack([c, a], 1)], axis=1)  # [C, 3, 2]
    lo, hi = e0.min(axis=2), e0.max(axis=2)
    return lo * int(num_vertices) + hi, lo, hi                       # [C, 3]


def new_vertex_count(triangles, chosen, num_vertices):
    """Midpoint vertices that splitting the first j chosen triangles adds, for every j: ``[C + 1]``."""
    keys, _, _ = _edge_keys(triangles, chosen, num_vertices)
    _, first = np.unique(keys.ravel(), return_index=True)
    first_tri = np.sort(first // 3)
    return np.searchsorted(first_tri, np.arange(len(chosen) + 1), side="left")


def subdivide(triangles, chosen, num_vertices):
    """Midpoint subdivision of the ``chosen`` triangles (each -> 4, parents removed).

    Returns ``(triangles [M'], edges [E, 2], parent [M'])``: unchosen triangles first in their
    order, then 4 children per chosen triangle; midpoint vertex ``num_vertices + e`` lies on
    edge ``edges[e]`` (one per distinct edge: shared between chosen neighbours); ``parent``
    is the old index of each new triangle. Orientation is kept."""
    t = np.asarray(triangles, np.int64).reshape(-1, 3)
    chosen = np.asarray(chosen, np.int64)
    n = int(num_vertices)
    keep = np.ones(len(t), bool)
    keep[chosen] = False
    if len(chosen) == 0:
        return t.copy(), np.zeros((0, 2), np.int64), np.arange(len(t))
    keys, lo, hi = _edge_keys(t, chosen, n)
    uniq, first, inv = np.unique(keys.ravel(), return_index=True, return_inverse=True)
    edges = np.stack([lo.ravel()[first], hi.ravel()[first]], axis=1)
    mid = n + inv.reshape(-1, 3)                                      # [C, 3]: m_ab, m_bc, m_ca
    a, b, c = t[chosen, 0], t[chosen, 1], t[chosen, 2]
    mab, mbc, mca = mid[:, 0], mid[:, 1], mid[:, 2]
    children = np.stack([np.stack([a, mab, mca], 1), np.stack([mab, b, mbc], 1),
                         np.stack([mca, mbc, c], 1), np.stack([mab, mbc, mca], 1)], axis=1).reshape(-1, 3)
    out = np.concatenate([t[keep], children])
    parent = np.concatenate([np.flatnonzero(keep), np.repeat(chosen, 4)])
    return out, edges, parent


# ---------------------------------------------------------------------- device kernel


class MaxWeightAccumulate(Stage):
    stage = "max_weight_accumulate"

    def __call__(self, enc, weights, acc, m, reset=False, profiler=None):
        ap = self.uniform("AccParams", num_triangles=m, reset=int(bool(reset)))
        self.dispatch(enc, max(1, (int(m) + 255) // 256), dict(ap=ap, weights=weights, acc=acc), profiler)


# ---------------------------------------------------------------------- the strategy


#: per-vertex arrays of the trainer's state and their row layout (vertex axis)
_VERTEX_KEYS = ("positions", "sh", "logits", "exp_avg_positions", "exp_avg_sq_positions", "exp_avg_sh",
                "exp_avg_sq_sh", "exp_avg_logits", "exp_avg_sq_logits")


class TopologyStrategy:
    """Prune / densify hooks for :class:`~.trainer.Trainer` (see the module docstring).

    Args:
        schedule: the run's :class:`~.schedules.Schedule`.
        seed: the run's seed (sampling).
        max_vertices: densification cap (method.md: 3M).
        stop_rel, stop_windows: the densification stop (0 disables it).
        enabled: False turns every edit off (the per-step accumulation still runs).
    """

    def __init__(self, schedule, seed=0, max_vertices=3_000_000, stop_rel=0.01, stop_windows=3, enabled=True,
                 near=0.01):
        self.sched = schedule
        self.seed = int(seed)
        self.max_vertices = int(max_vertices)
        self.stop_rel = float(stop_rel)
        self.stop_windows = int(stop_windows)
        self.enabled = bool(enabled)
        self.near = float(near)
        self.ring_size = max(1, schedule.topology_every())
        self.seen = set()              # training views rendered since the last weight reset
        self.l1_windows = []           # mean training L1 per topology window
        self.last_read = 0             # iteration of the last ring read
        self.densify_stopped = None    # reason, once stopped
        self.events = []               # log records not yet written
        self.kernel = None

    # -------------------------------------------------------------- device state
    def attach(self, trainer, max_weight=None):
        """(Re)allocate the accumulator for the trainer's current triangles."""
        c = trainer.ctx
        if self.kernel is None:
            self.kernel = MaxWeightAccumulate(c)
            self.ring = c.upload(np.zeros(self.ring_size, np.float32), "train_l1_ring")
        mw = np.zeros(trainer.m, np.float32) if max_weight is None else np.asarray(max_weight, np.float32)
        self.acc = c.upload(mw, "max_weight_acc")

    def max_weight(self, trainer):
        return trainer.ctx.read(self.acc, np.float32, trainer.m)

    def state(self):
        return dict(seen=sorted(int(v) for v in self.seen), l1_windows=list(self.l1_windows),
                    last_read=self.last_read, densify_stopped=self.densify_stopped)

    def load_state(self, trainer, state, max_weight, ring=None):
        self.seen = set(state.get("seen", []))
        self.l1_windows = list(state.get("l1_windows", []))
        self.last_read = int(state.get("last_read", 0))
        self.densify_stopped = state.get("densify_stopped")
        self.attach(trainer, max_weight)
        if ring is not None:
            trainer.ctx.queue.write_buffer(self.ring, 0, np.asarray(ring, np.float32).tobytes())

    def ring_values(self, trainer):
        return trainer.ctx.read(self.ring, np.float32, self.ring_size)

    # -------------------------------------------------------------- hooks
    def pre_step(self, trainer, it):
        """Nothing to do before a step (kept for the strategy interface)."""

    def post_step(self, trainer, it, result, view, loss_buf, enc, profiler=None):
        """Record the step's accumulation into ``enc``; returns True when ``it`` is a topology
        step (the trainer then submits and calls :meth:`edit`)."""
        self.kernel(enc, result.buffers["max_weight"], self.acc, trainer.m, profiler=profiler)
        enc.copy_buffer_to_buffer(loss_buf, 4, self.ring, 4 * (it % self.ring_size), 4)
        self.seen.add(int(view))
        s = self.sched
        return self.enabled and (s.is_prune_step(it) or s.is_densify_step(it))

    def _read_l1_window(self, trainer, it):
        ring = self.ring_values(trainer)
        count = min(self.ring_size, it - self.last_read)
        if count <= 0:
            return
        idx = [(i % self.ring_size) for i in range(it - count + 1, it + 1)]
        self.l1_windows.append(float(np.mean(ring[idx])))
        self.last_read = it

    def _check_stop(self, it, num_vertices):
        if self.densify_stopped is not None:
            return
        k = self.stop_windows
        if num_vertices >= self.max_vertices:
            self.densify_stopped = f"max-vertices reached ({num_vertices} >= {self.max_vertices})"
        elif self.stop_rel > 0 and k > 0 and len(self.l1_windows) >= 2 * k:
            prev = float(np.mean(self.l1_windows[-2 * k:-k]))
            now = float(np.mean(self.l1_windows[-k:]))
            rel = (prev - now) / max(prev, 1e-12)
            if rel < self.stop_rel:
                self.densify_stopped = (f"training L1 stopped improving: mean over the last {k} windows {now:.5f} vs "
                                        f"{prev:.5f} before, relative improvement {rel:.4f} < {self.stop_rel}")
        if self.densify_stopped is not None:
            self.events.append(dict(iteration=it, event="densify_stop", reason=self.densify_stopped,
                                    vertices=int(num_vertices)))

    def edit(self, trainer, it):
        """The topology step at iteration ``it`` (one host round trip)."""
        s = self.sched
        a = trainer.state_arrays()
        n, k = a["positions"].shape[0], a["sh_planar"].shape[0]
        tris = a["triangles"]
        mw = self.max_weight(trainer)
        self._read_l1_window(trainer, it)
        floor = s.opacity_floor(it)
        v = dict(positions=a["positions"].astype(np.float64), sh=a["sh_planar"].transpose(1, 0, 2).astype(np.float64),
                 logits=a["logits"].astype(np.float64))
        for key, shape in (("positions", (n, 3)), ("sh", None), ("logits", (n,))):
            for mom in ("exp_avg", "exp_avg_sq"):
                arr = a[f"{mom}_{key}"].astype(np.float64)
                v[f"{mom}_{key}"] = arr.reshape(k, n, 3).transpose(1, 0, 2) if key == "sh" else arr.reshape(shape)
        rec = dict(iteration=it, event="topology", vertices_before=n, triangles_before=len(tris))
        reset = False
        if s.is_prune_step(it):
            thr = s.prune_threshold(it)
            criteria = s.prune_criteria()           # the ablations switch the first two off
            drop = np.zeros(len(tris), bool)
            if "opacity" in criteria:
                opacity = opacity_from_logit(v["logits"], floor)
                drop = opacity[tris].min(axis=1) <= thr                 # the hard prune's criterion
                rec["pruned_opacity"] = int(drop.sum())
            all_seen = set(trainer.train_views) <= self.seen
            if "weight" not in criteria:
                rec["weight_prune_skipped"] = "weight_prune off"
            elif all_seen:
                low = mw <= thr
                rec["pruned_weight"] = int((low & ~drop).sum())
                drop |= low
                reset = True
            else:
                rec["weight_prune_skipped"] = "not every training view rendered since the last reset"
            big = projected_sizes(v["positions"], tris, [trainer.scene.cameras[i] for i in trainer.train_views],
                                  self.near) > s.prune_max_size()
            rec["pruned_size"] = int((big & ~drop).sum())
            drop |= big
            if drop.all():        # never leave an empty model: keep the heaviest triangle
                drop[int(np.argmax(mw))] = False
            rec["hard_prune"] = s.is_hard_prune_step(it)
            rec["threshold"] = thr
            tris, mw = tris[~drop], mw[~drop]
        tris, old_from_new = remove_unused_vertices(tris, n)
        v = {key: arr[old_from_new] for key, arr in v.items()}
        n = len(old_from_new)
        if s.is_densify_step(it):
            self._check_stop(it, n)
            if self.densify_stopped is None:
                rng = np.random.default_rng([self.seed, int(it), 1])
                count = s.densify_count(n, cap=self.max_vertices)
                areas = triangle_areas(v["positions"], tris)
                chosen = choose_split(mw, areas, count, s.densify_always_largest(), rng)
                if len(chosen):
                    added = new_vertex_count(tris, chosen, n)
                    budget = max(0, self.max_vertices - n)
                    chosen = chosen[:max(0, int(np.searchsorted(added, budget, side="right")) - 1)]
                tris, edges, parent = subdivide(tris, chosen, n)
                mw = mw[parent]
                op = opacity_from_logit(v["logits"], floor)
                new_op = 0.5 * (op[edges[:, 0]] + op[edges[:, 1]])
                for key in list(v):
                    mid = 0.5 * (v[key][edges[:, 0]] + v[key][edges[:, 1]])
                    if key == "logits":
                        mid = logit_from_opacity(new_op, floor)
                    v[key] = np.concatenate([v[key], mid])
                rec["split"] = int(len(chosen))
                rec["split_requested"] = int(count)
                n = len(v["positions"])
        if reset:
            mw = np.zeros(len(tris), np.float32)
            self.seen = set()
        adam = {key: (v[f"exp_avg_{key}"].transpose(1, 0, 2).ravel() if key == "sh" else v[f"exp_avg_{key}"].ravel(),
                      v[f"exp_avg_sq_{key}"].transpose(1, 0, 2).ravel() if key == "sh"
                      else v[f"exp_avg_sq_{key}"].ravel()) for key in ("positions", "sh", "logits")}
        trainer._set_model(v["positions"], tris, v["sh"], v["logits"], adam=adam, max_weight=mw)
        rec.update(vertices=trainer.n, triangles=trainer.m)
        self.events.append(rec)
        return rec


__all__ = ["TopologyStrategy", "MaxWeightAccumulate", "max_weight_accumulate_reference", "triangle_areas",
           "projected_sizes", "remove_unused_vertices", "choose_split", "subdivide", "new_vertex_count"]
