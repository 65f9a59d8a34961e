"""The trainer's optimiser step: one Adam step of each parameter group (positions, opacity
logits, SH with its DC at its own rate), the positions' learning rate scaled per vertex by its
distance to the nearest training camera (``config.position_lr_depth``).

Why the scale: Adam moves a vertex by about the learning rate per step whatever its depth, so a
vertex close to a camera moves many more pixels a step than a far one, and on a capture walked
through a street (lund: the initial points a median 0.047 camera radii from their nearest
training camera) the near house fronts and the ground turn into shards within tens of steps.
Times ``min(1, d)`` (``d`` in the trainer's frame, camera radius 1) the step is about the same
angle from the nearest camera below ``d = 1`` and the paper's beyond. The scale is read from the
positions before each step on the device (:class:`~tsplus_wgpu.kernels.optim.DepthScale`), so it
holds no state and a resumed run recomputes it exactly.
"""

from __future__ import annotations

import numpy as np

from ..kernels.optim import Adam, DepthScale

#: the distance (frame units, camera radius 1) from the nearest training camera beyond which a
#: vertex takes the full position learning rate
DEPTH_REACH = 1.0


class ParamOptimizer:
    """Records the optimiser step of a :class:`~.trainer.Trainer` (its parameter buffers,
    gradients and moments) into an encoder."""

    def __init__(self, ctx, centres, by_depth=True):
        """``centres [C, 3]``: the training cameras' centres in the trainer's frame."""
        self.ctx = ctx
        self.adam = Adam(ctx)
        self.by_depth = bool(by_depth) and len(centres) > 0
        if self.by_depth:
            self.depth = DepthScale(ctx)
            self.centres, self.num_centres = self.depth.centres(np.asarray(centres).reshape(-1, 3)), len(centres)

    def record(self, enc, t, it, profiler=None):
        """Adam on every group of trainer ``t`` at 1-based iteration ``it``."""
        lr = t.sched.learning_rates(it)
        n, k = t.n, t.k
        pos = dict(lr=lr["positions"])
        if self.by_depth and lr["positions"] > 0 and n:
            scale = t.renderer.scratch.get("position_lr_scale", 4 * n)
            self.depth(enc, t.params["positions"], self.centres, scale, n, self.num_centres, DEPTH_REACH, profiler)
            pos.update(scale=scale, stride=3)
        # the SH [N, K, 3]: the first 3 floats of every vertex's 3K are its DC (lr sh_dc), the rest sh_rest
        groups = (("positions", pos, 3 * n), ("logits", dict(lr=lr["opacity"]), n),
                  ("sh", dict(lr=lr["sh_dc"], lr_tail=lr["sh_rest"], period=3 * k, head=3), 3 * n * k))
        for key, rates, size in groups:
            m1, m2 = t.moments[key]
            self.adam.record(enc, t.params[key], t.pgrad[key], m1, m2, size, step=it, profiler=profiler, **rates)
