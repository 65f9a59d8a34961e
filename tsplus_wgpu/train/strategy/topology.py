"""Pruning and densification of Triangle Splatting+ (method.md) as a strategy object with
pre/post-step hooks, apart from the rasterizer: :class:`TopologyStrategy`. Its edits map one
:class:`~..state.VertexState` to a new one through the pure operations of :mod:`.ops`; the
trainer reads its state, hands it over and installs what comes back
(:meth:`~..trainer.Trainer.apply_topology`).

Per step (``post_step``, on the device, no readback): the forward pass's per-triangle max
blending weight is folded into a running maximum (``max_weight_accumulate.wgsl``, kernel
:class:`~...kernels.topology.MaxWeightAccumulate`), and the step's training L1 is copied into a ring
buffer (for the densification stop).

At a topology step (every 500 iterations, scaled with ``quick``; one host round trip):

1. **Prune** (``Schedule.is_prune_step``: every 500 after 4000 [3000]; the criteria of
   ``Schedule.prune_criteria``, all three unless an ablation switches one off): delete triangles whose
   min vertex opacity <= thr, whose max blending weight over the training views <= thr, or
   whose projected size (max vertex-to-centroid distance, px, max over the training views in
   front of the near plane) > 1400 [1300]; thr = ``Schedule.prune_threshold``. Triangles of the
   background shell (:mod:`..shell`, group ``SHELL``) are exempt from the opacity and weight
   tests: they are the backdrop that keeps pixels covered while the surface in front is still
   semi-transparent (the final cleanup's weight test still applies to them). From the hard
   prune on, a prune that applies the weight test also deletes the shell triangles hidden
   behind the surfaces (inside some training view's image, with max weight <=
   :data:`SHELL_HIDDEN` in every one): they would only hold vertices and time. The **hard
   prune** (``is_hard_prune_step``, 5000) is the opacity criterion (the paper's "remove all
   triangles with opacity below T_o"); it is also part of every regular prune, so at 5000 the
   two coincide. The weight criterion needs the maximum over *all* training views: when the
   views rendered since the last reset do not cover them (a quick run's interval is shorter
   than an epoch), that prune skips the weight criterion and the maximum keeps accumulating;
   the maximum is reset after each prune that applied it. **Early prune** (a quick run,
   ``quick_early_prune``; ``Schedule.is_early_prune_step``): each densify step before the first
   prune step first deletes the surface triangles whose min vertex opacity is <= thr (the
   opacity test alone, :meth:`TopologyStrategy.early_prune_mask`).
2. **Remove unused vertices** and compact the indices (:func:`.ops.remove_unused`).
3. **Densify** (``is_densify_step``: every 500 in (500, 13000) [(1000, 25000)]) unless
   stopped: ``n = min(cap, 1.23 [1.27] V) - V`` (``Schedule.densify_count``, cap = the run's
   vertex cap, :mod:`.cap`; n <= 0: nothing) triangles drawn without replacement with probability
   proportional to the max blending weight (0 where the 3D area < 7.5e-5; at most as many as
   have a non-zero probability, so all-zero weights draw none), plus the 100 [500] largest by
   area, not counting the shell's (far away, large in 3D but not on screen) (:func:`.ops.choose_split`). Each becomes 4 (:func:`.ops.densify`); a midpoint vertex is keyed
   by its edge, so two chosen neighbours share it; it gets the mean position, SH and
   activated opacity of the edge's two vertices; parents are removed. The chosen list is cut
   (largest last) so that neither V nor M passes the cap (:mod:`.cap`: vertices, and the
   triangles one storage binding holds). Children inherit their parent's
   running max weight (only matters before the first weight prune resets it).

**Adam state follows every edit**: rows of surviving vertices are kept (moved with the index
compaction); a midpoint vertex gets the *mean* of its edge's two vertices' first and second
moments (its parameters are that mean too, so its first step is as large as its parents'
rather than the ~3x larger step a zero second moment gives).

**Densification stop** ("model only what the scene needs"): at each topology step the mean
training L1 of the iterations since the previous topology step is appended to a history; at
each densify step, with S_now the mean of the last K windows and S_prev the mean of the K before (K =
``densify_stop_windows``, 3), densification stops for good when the L1 is flat,
``|S_prev - S_now| / S_prev < densify_stop_rel`` (0.01; 0 disables). The reason is logged
(``event: densify_stop``). At the cap (V reached it, or M has no room for one more split)
densification only *pauses*: the prunes that follow free vertices, and the next densify step
below the cap grows the model again (``event: densify_paused`` with the bound's reason: max-vertices,
vertex budget or storage-binding limit; ``event: densify_resumed``). The cap itself is in a first
``event: vertex_cap`` record. Until 2026-11-28 reaching the cap stopped densifying for good: a
run whose initial mesh (about 12 Delaunay faces a point) met the cap before the hard prune kept
what that prune left (lund at a quarter of the default pixels, seed 1: 3,900 vertices of a
13,490 budget). A *rise* of the L1 is not a plateau: the schedule
causes it (a prune, sigma falling, the opacity floor rising), not the model's size. Until
2026-11-27 a rise stopped densifying too; on office's default CPU run it fired at iteration
710, on a 9 % rise across the second prune, at 44,663 vertices; growing on to the vertex
budget (64,800) gave 25.11 dB against 24.90 held out, in 605 s of training against 555
(docs/measurements.md). Before the vertex budget existed a rise was the only thing that held a
run back (procedural:small kept densifying to 240,209 vertices without it); the budget now
bounds every run.

Sampling uses ``numpy.random.default_rng([seed, iteration, 1])``: stateless, so a resumed run
draws what an uninterrupted one draws.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ...kernels.topology import MaxWeightAccumulate
from ..schedules import opacity_from_logit
from ..shell import SHELL

#: max blending weight (over every training view since the last reset) at or below which a
#: shell triangle counts as hidden (1/255: under one step of an 8-bit image)
SHELL_HIDDEN = 1.0 / 255.0
from . import ops
from .cap import VertexCap


def _keep_one(drop, weights):
    """Never leave an empty model: where ``drop`` takes every triangle, keep the heaviest (in place)."""
    if drop.all():
        drop[int(np.argmax(weights))] = False


class TopologyStrategy:
    """Prune / densify hooks for :class:`~..trainer.Trainer` (see the module docstring).

    Args:
        schedule: the run's :class:`~..schedules.Schedule`.
        seed: the run's seed (sampling).
        max_vertices: densification cap: a number (method.md: 3M), or the run's
            :class:`~.cap.VertexCap` (:func:`~.cap.vertex_cap`: the smallest of ``max_vertices``,
            the vertex budget and the device's storage-binding limit), which names the bound in
            the densify_stop reason and in a first ``event: vertex_cap`` log record.
        stop_rel, stop_windows: the densification stop (0 disables it).
        enabled: False turns every edit off (the per-step accumulation still runs).
        near: near plane of the size criterion (scene units).
    """

    def __init__(self, schedule, seed=0, max_vertices=3_000_000, stop_rel=0.01, stop_windows=3, enabled=True,
                 near=0.01):
        self.sched = schedule
        self.seed = int(seed)
        self.cap = max_vertices if isinstance(max_vertices, VertexCap) else VertexCap(int(max_vertices))
        self.max_vertices = self.cap.vertices
        self.stop_rel = float(stop_rel)
        self.stop_windows = int(stop_windows)
        self.enabled = bool(enabled)
        self.near = float(near)
        self.ring_size = max(1, schedule.topology_every())
        self.seen = set()              # training views rendered since the last weight reset
        self.l1_windows = []           # mean training L1 per topology window
        self.last_read = 0             # iteration of the last ring read
        self.densify_stopped = None    # reason, once stopped
        self.at_cap = None             # the cap's reason while densification is paused at it
        self.events = [self.cap.record()] if self.enabled else []   # log records not yet written
        self.kernel = None
        self.ctx = None
        self.m = 0                     # triangles the accumulator holds

    # -------------------------------------------------------------- device state
    def attach(self, ctx, num_triangles, max_weight=None):
        """(Re)allocate the accumulator for ``num_triangles`` triangles, seeded with
        ``max_weight [M]`` (default zeros)."""
        if self.kernel is None:
            self.ctx = ctx
            self.kernel = MaxWeightAccumulate(ctx)
            self.ring = ctx.upload(np.zeros(self.ring_size, np.float32), "train_l1_ring")
        self.m = int(num_triangles)
        mw = np.zeros(self.m, np.float32) if max_weight is None else np.asarray(max_weight, np.float32)
        self.acc = ctx.upload(mw, "max_weight_acc")

    def max_weight(self):
        """The running max blending weight of each triangle, read back: ``[M]`` float32."""
        return self.ctx.read(self.acc, np.float32, self.m)

    def ring_values(self):
        """The ring of per-iteration training L1 values, read back."""
        return self.ctx.read(self.ring, np.float32, self.ring_size)

    def state(self):
        """The host-side state for checkpoints (JSON)."""
        return dict(seen=sorted(int(v) for v in self.seen), l1_windows=list(self.l1_windows),
                    last_read=self.last_read, densify_stopped=self.densify_stopped, at_cap=self.at_cap)

    def load_state(self, state, ring=None):
        """Continue from :meth:`state` and the checkpoint's L1 ring (after :meth:`attach`)."""
        self.seen = set(state.get("seen", []))
        self.l1_windows = list(state.get("l1_windows", []))
        self.last_read = int(state.get("last_read", 0))
        self.densify_stopped = state.get("densify_stopped")
        self.at_cap = state.get("at_cap")
        if ring is not None:
            self.ctx.queue.write_buffer(self.ring, 0, np.asarray(ring, np.float32).tobytes())

    # -------------------------------------------------------------- hooks
    def is_edit_step(self, it):
        """Whether iteration ``it`` prunes or densifies."""
        s = self.sched
        return self.enabled and (s.is_prune_step(it) or s.is_densify_step(it))

    def pre_step(self, trainer, it):
        """Nothing to do before a step (kept for the strategy interface)."""

    def post_step(self, trainer, it, result, view, loss_buf, enc, profiler=None):
        """Record the step's accumulation into ``enc``; returns True when ``it`` is a topology
        step (the trainer then submits and calls :meth:`~..trainer.Trainer.apply_topology`)."""
        self.kernel(enc, result.buffers["max_weight"], self.acc, self.m, profiler=profiler)
        enc.copy_buffer_to_buffer(loss_buf, 4, self.ring, 4 * (it % self.ring_size), 4)
        self.seen.add(int(view))
        return self.is_edit_step(it)

    def read_l1_window(self, it):
        """Append the mean training L1 since the last read to the history."""
        ring = self.ring_values()
        count = min(self.ring_size, it - self.last_read)
        if count <= 0:
            return
        idx = [(i % self.ring_size) for i in range(it - count + 1, it + 1)]
        self.l1_windows.append(float(np.mean(ring[idx])))
        self.last_read = it

    def check_stop(self, it, num_vertices, num_triangles=0):
        """Stop densifying for good when the training L1 stopped improving; pause while the
        model is at the cap (vertices, or triangles: no room for one more split). Returns True
        when densification may go on at ``it``."""
        if self.densify_stopped is not None:
            return False
        k = self.stop_windows
        if self.stop_rel > 0 and k > 0 and len(self.l1_windows) >= 2 * k:
            prev = float(np.mean(self.l1_windows[-2 * k:-k]))
            now = float(np.mean(self.l1_windows[-k:]))
            rel = (prev - now) / max(prev, 1e-12)
            if abs(rel) < self.stop_rel:        # flat: a rise is the schedule's doing, not a plateau
                self.densify_stopped = (f"training L1 stopped improving: mean over the last {k} windows {now:.5f} vs "
                                        f"{prev:.5f} before, relative change {rel:.4f} within {self.stop_rel}")
        if self.densify_stopped is not None:
            self.events.append(dict(iteration=it, event="densify_stop", reason=self.densify_stopped,
                                    vertices=int(num_vertices)))
            return False
        at_cap = None
        if num_vertices >= self.max_vertices:
            at_cap = self.cap.reached(num_vertices)
        elif self.cap.triangles is not None and num_triangles + 3 > self.cap.triangles:
            at_cap = self.cap.triangles_reached(num_triangles)
        if (at_cap is None) != (self.at_cap is None):
            self.events.append(dict(iteration=it, event="densify_paused" if at_cap else "densify_resumed",
                                    vertices=int(num_vertices), **({"reason": at_cap} if at_cap else {})))
        self.at_cap = at_cap
        return at_cap is None

    # -------------------------------------------------------------- the edit
    def edit(self, state, it, train_views, cameras):
        """The topology step at iteration ``it``: returns the new :class:`~..state.VertexState`
        (``state`` as the trainer read it, max weights included; ``train_views`` the scene's
        training view indices, ``cameras`` their cameras). Logs an ``event: topology`` record."""
        s = self.sched
        self.read_l1_window(it)
        rec = dict(iteration=it, event="topology", vertices_before=state.n, triangles_before=state.m)
        reset = False
        if s.is_prune_step(it):
            drop, reset = self.prune_mask(state, it, train_views, cameras, rec)
            state = ops.prune(state, drop)
        elif s.is_early_prune_step(it):
            state = ops.prune(state, self.early_prune_mask(state, it, rec))
        else:
            state = ops.remove_unused(state)
        if s.is_densify_step(it):
            if self.check_stop(it, state.n, state.m):
                state = self.densify(state, it, rec)
        if reset:
            state = replace(state, max_weight=np.zeros(state.m, np.float32))
            self.seen = set()
        rec.update(vertices=state.n, triangles=state.m)
        self.events.append(rec)
        return state

    def prune_mask(self, state, it, train_views, cameras, rec):
        """``(drop [M], reset)``: the triangles the prune at ``it`` deletes (the criteria of
        ``Schedule.prune_criteria``), and whether the weight criterion applied (the running
        maximum is then reset). Counts go to ``rec``."""
        s = self.sched
        tris, mw = state.triangles, state.weights()
        thr = s.prune_threshold(it)
        criteria = s.prune_criteria()           # the ablations switch the first two off
        drop = np.zeros(len(tris), bool)
        reset = False
        if "opacity" in criteria:
            drop = self.low_opacity(state, it)                      # the hard prune's criterion
            rec["pruned_opacity"] = int(drop.sum())
        if "weight" not in criteria:
            rec["weight_prune_skipped"] = "weight_prune off"
        elif set(train_views) <= self.seen:
            low = mw <= thr
            rec["pruned_weight"] = int((low & ~drop).sum())
            drop |= low
            reset = True
        else:
            rec["weight_prune_skipped"] = "not every training view rendered since the last reset"
        shell = state.group_of() == SHELL      # the backdrop: kept by the opacity and weight tests
        if shell.any():
            # ... unless hidden: from the hard prune on, a shell triangle that no training view
            # saw with a weight above SHELL_HIDDEN since the last reset is behind the surfaces
            hidden = np.zeros_like(shell)
            if reset and it >= s.floor_start():      # (one no view can show is the backdrop of other views)
                hidden[shell] = mw[shell] <= SHELL_HIDDEN
                hidden[hidden] = ops.in_views(state.positions, tris[hidden], cameras, self.near)
            rec["shell_kept"] = int((drop & shell & ~hidden).sum())
            rec["shell_hidden"] = int(hidden.sum())
            drop = (drop & ~shell) | hidden
        big = np.zeros_like(drop)         # sized only where nothing else drops (half the triangles or less)
        big[~drop] = ops.projected_sizes(state.positions, tris[~drop], cameras, self.near) > s.prune_max_size()
        rec["pruned_size"] = int(big.sum())
        drop |= big
        _keep_one(drop, mw)
        rec["hard_prune"] = s.is_hard_prune_step(it)
        rec["threshold"] = thr
        return drop, reset

    def early_prune_mask(self, state, it, rec):
        """``drop [M]`` of a quick run's early prune (``Schedule.is_early_prune_step``): the surface
        triangles whose min vertex opacity is at or below the prune threshold. Only the opacity
        test: the weight test's threshold would also take the layers behind the front one, still
        at about the initial opacity; the running max weight is not reset. Counts go to ``rec``."""
        drop = self.low_opacity(state, it) & (state.group_of() != SHELL)
        _keep_one(drop, state.weights())
        rec["pruned_early"] = int(drop.sum())
        rec["threshold"] = self.sched.prune_threshold(it)
        return drop

    def low_opacity(self, state, it):
        """``[M]`` bool: the triangles whose min vertex opacity is at or below the prune threshold
        at ``it`` (the hard prune's criterion)."""
        s = self.sched
        opacity = opacity_from_logit(state.logits, s.opacity_floor(it))
        return opacity[state.triangles].min(axis=1) <= s.prune_threshold(it)

    def densify(self, state, it, rec):
        """Split triangles drawn by max weight plus the largest (never past the cap: vertices, and
        triangles, 3 more a split)."""
        s = self.sched
        n = state.n
        rng = np.random.default_rng([self.seed, int(it), 1])
        count = s.densify_count(n, cap=self.max_vertices)
        areas = ops.triangle_areas(state.positions, state.triangles)
        chosen = ops.choose_split(state.weights(), areas, count, s.densify_always_largest(), rng,
                                  largest_from=state.group_of() != SHELL)
        if len(chosen):
            added = ops.new_vertex_count(state.triangles, chosen, n)
            budget = max(0, self.max_vertices - n)
            chosen = chosen[:max(0, int(np.searchsorted(added, budget, side="right")) - 1)]
            if self.cap.triangles is not None:
                chosen = chosen[:max(0, (self.cap.triangles - state.m) // 3)]
        state = ops.densify(state, chosen, s.opacity_floor(it))
        rec["split"] = int(len(chosen))
        rec["split_requested"] = int(count)
        return state


__all__ = ["TopologyStrategy"]
