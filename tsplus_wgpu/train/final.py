"""The end of training: the exported mesh (:func:`final_mesh`).

method.md's cleanup renders every training view with the trained model and deletes the
triangles whose max blending weight is <= 0.5 (``config.final_prune``, off by default: those
triangles are the hidden layers other viewpoints see; never the shell's triangles beyond every
training view's image, the backdrop of other viewpoints), then the unused vertices; sigma and
opacity are dropped. The vertex colours are then either the SH DC term (``config.mesh_colors =
'dc'``) or fitted to the training photos through the exported, depth-tested mesh (``'fit'``,
:func:`~tsplus_wgpu.render.mesh_fit.fit_vertex_colors`): an engine draws one colour per
vertex, and the SH DC term is the colour's mean over the whole sphere rather than over the
directions the photos saw.
"""

from __future__ import annotations

import numpy as np

from ..kernels.loss import supersampled_camera
from ..types import SH_C0
from .schedules import FINAL_PRUNE_WEIGHT
from .shell import beyond_views

#: samples per pixel side of the colour fit (reduced for large images, mesh_fit.MAX_SAMPLES)
FIT_SUPERSAMPLE = 2


def final_mesh(trainer):
    """``(positions [V, 3] in world units, triangles [F, 3], colors [V, 3] in [0, 1])`` of
    ``trainer``'s model (module docstring)."""
    t, cfg = trainer, trainer.config
    sigma = t.sched.sigma(t.iteration)
    ss = t.sched.supersample(t.iteration)     # as the last training steps rendered
    mw = np.full(t.m, np.inf if not cfg.final_prune else 0.0, np.float32)  # off: all kept
    for v in t.train_views if cfg.final_prune else ():
        cam = t.scene.cameras[v]
        res = t.renderer.forward(t.model, supersampled_camera(cam, t.fit_supersample(cam, ss)), sigma,
                                 cfg.background, cfg.near)
        mw = np.maximum(mw, res.max_weight)
    model = t.current_model()
    pos = t.ctx.read(t.params["positions"], np.float32, 3 * t.n).reshape(t.n, 3)   # the trainer's frame
    keep = (mw > FINAL_PRUNE_WEIGHT) | beyond_views(t.groups, pos, t.triangles_host, [
        t.scene.cameras[v] for v in t.train_views], cfg.near)   # the backdrop of other viewpoints
    tris = model.triangles[keep]
    used = np.zeros(model.num_vertices, bool)
    used[tris.ravel()] = True
    new_from_old = np.cumsum(used) - 1
    tris = new_from_old[tris]
    colors = np.clip(model.sh[used, 0] * SH_C0 + 0.5, 0.0, 1.0)
    if cfg.mesh_colors == "fit" and len(tris):
        colors = fitted_colors(t, pos[used], tris, colors)
    return model.positions[used], tris, colors


def fitted_colors(trainer, positions, triangles, prior):
    """The least-squares vertex colours of the mesh ``(positions, triangles)`` (in the
    trainer's frame) against the training photos, drawn as ``tsplus eval`` draws it."""
    from ..render.mesh_fit import fit_vertex_colors
    t = trainer
    views = list(t.train_views)
    colors, info = fit_vertex_colors(positions, triangles, [t.scene.cameras[v] for v in views],
                                     [t.scene.images[v] for v in views], prior, t.config.near, t.mesh_renderer,
                                     supersample=FIT_SUPERSAMPLE, background=t.config.background)
    t.color_fit = info
    return colors
