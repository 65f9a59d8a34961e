"""The model a run starts from (:class:`~.trainer.Trainer` without ``model``).

1. The scene's points meshed (:func:`~.init.init_from_points`): every face of their 3D
   Delaunay tetrahedralisation, less the faces that a training camera's line of sight to a
   point it observed crosses (``config.carve``, :mod:`.carve`; needs the scene's SfM tracks,
   ``Scene.point_tracks``) and the faces longer than ``config.init_max_edge`` local spacings.
2. The background shell (``config.shell``, :mod:`.shell`), a triangle group of its own.

Tracks count only from training views: a held-out view must not shape the model.
"""

from __future__ import annotations

import numpy as np

from ..data.tracks import rays
from .init import init_from_points
from .shell import background_shell, with_shell


def training_rays(scene):
    """``(ray_pt [R], origins [R, 3])``: one row per observation of a point by a training
    view (the point's row in ``scene.points``, that camera's centre), or None without tracks."""
    tracks = scene.point_tracks
    if tracks is None or scene.points is None:
        return None
    if len(tracks[0]) != len(scene.points) + 1:
        raise ValueError(f"scene: point_tracks has {len(tracks[0]) - 1} tracks for {len(scene.points)} points")
    ray_pt, views = rays(tracks)
    train = np.zeros(len(scene.cameras), bool)
    train[list(scene.train_indices)] = True
    ok = train[views]
    centres = np.stack([c.center for c in scene.cameras])
    return ray_pt[ok], centres[views[ok]]


def initial_model(scene, config):
    """``(model, groups, info)``: the starting :class:`~tsplus_wgpu.TriangleModel` in the
    scene's units, its triangle groups (:mod:`.shell`) and the points mesh's
    :class:`~.init.InitInfo`."""
    if scene.points is None or len(scene.points) < 3:
        raise ValueError("scene: it has no initial points (need at least 3 to triangulate)")
    vis = training_rays(scene) if config.carve else None
    model, info = init_from_points(scene.points, scene.point_colors, sh_degree=config.sh_degree,
                                   max_edge_ratio=config.init_max_edge or None, visibility=vis, return_info=True)
    shell = None
    if config.shell:
        views = list(scene.train_indices)
        shell = background_shell([scene.cameras[i] for i in views], [scene.images[i] for i in views], scene.points,
                                 sh_degree=config.sh_degree)
    model, groups = with_shell(model, shell)
    return model, groups, info
