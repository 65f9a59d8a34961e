"""The model a run starts from (:class:`~.trainer.Trainer` without ``model``).

1. The scene's points (at most :func:`bounded_points` of them) meshed
   (:func:`~.init.init_from_points`): every face of their 3D Delaunay tetrahedralisation and
   (``config.view_faces``) of each training view's 2-D Delaunay triangulation of the points it
   observed (:func:`~.init.view_faces`; needs the tracks), less
   the faces that a training camera's line of sight to a point it observed crosses
   (``config.carve``, :mod:`.carve`; needs the scene's SfM tracks, ``Scene.point_tracks``) and
   the faces longer than ``config.init_max_edge`` local spacings, and the faces on the path the
   training cameras moved along (``config.clear_path``, :func:`~.floaters.near_path`: the
   photographer walked through that space; lund's initial mesh has 11,384 such faces of 44,898,
   the cup 1, office and fox none).
2. The background shell (``config.shell``, :mod:`.shell`), a triangle group of its own.

Tracks count only from training views: a held-out view must not shape the model.
"""

from __future__ import annotations

import numpy as np

from ..data.tracks import rays, subset
from ..types import TriangleModel
from .floaters import near_path
from .init import init_from_points, view_faces
from .shell import background_shell, with_shell
from .strategy.cap import initial_points_bound


def training_rays(scene, tracks=None, num_points=None):
    """``(ray_pt [R], origins [R, 3])``: one row per observation of a point by a training
    view (the point's row in ``scene.points``, that camera's centre), or None without tracks.
    ``tracks`` / ``num_points``: another track table of that many points (default the scene's)."""
    tracks = scene.point_tracks if tracks is None else tracks
    if tracks is None or scene.points is None:
        return None
    num = len(scene.points) if num_points is None else int(num_points)
    if len(tracks[0]) != num + 1:
        raise ValueError(f"scene: point_tracks has {len(tracks[0]) - 1} tracks for {num} points")
    ray_pt, views = rays(tracks)
    train = np.zeros(len(scene.cameras), bool)
    train[list(scene.train_indices)] = True
    ok = train[views]
    centres = np.stack([c.center for c in scene.cameras])
    return ray_pt[ok], centres[views[ok]]


def training_observations(scene, tracks=None, num_points=None):
    """``[(camera, rows)]``: each training view's camera and the rows of the points it observed
    (:func:`training_rays`' observations grouped by view; empty without tracks)."""
    tracks = scene.point_tracks if tracks is None else tracks
    if tracks is None or scene.points is None:
        return []
    num = len(scene.points) if num_points is None else int(num_points)
    if len(tracks[0]) != num + 1:
        raise ValueError(f"scene: point_tracks has {len(tracks[0]) - 1} tracks for {num} points")
    ray_pt, views = rays(tracks)
    return [(scene.cameras[v], ray_pt[views == v]) for v in sorted(set(int(i) for i in scene.train_indices))]


def bounded_points(scene, config):
    """``(points, colours, tracks or None, dropped)``: the scene's initial points, at most
    :func:`~.strategy.cap.initial_points_bound` of them. Over the bound, the points that 3 or
    more training views observed come first, then the others, each in a fixed random order (the
    same for every seed), so the kept ones spread over the whole scene."""
    pts, cols, tracks = scene.points, scene.point_colors, scene.point_tracks
    views = list(scene.train_indices) or list(range(len(scene.cameras)))
    most = initial_points_bound(config, [scene.cameras[i] for i in views])
    if most is None or len(pts) <= most:
        return pts, cols, tracks, 0
    order = np.random.default_rng(0).permutation(len(pts))
    got = training_rays(scene)
    if got is not None:
        seen = np.bincount(got[0], minlength=len(pts))
        order = order[np.argsort(seen[order] < 3, kind="stable")]
    keep = np.sort(order[:most])
    return pts[keep], cols[keep], None if tracks is None else subset(tracks, keep), len(pts) - most


def initial_model(scene, config):
    """``(model, groups, info)``: the starting :class:`~tsplus_wgpu.TriangleModel` in the
    scene's units, its triangle groups (:mod:`.shell`) and the points mesh's
    :class:`~.init.InitInfo` (its ``num_bounded``: the points left out by :func:`bounded_points`)."""
    if scene.points is None or len(scene.points) < 3:
        raise ValueError("scene: it has no initial points (need at least 3 to triangulate)")
    pts, cols, tracks, dropped = bounded_points(scene, config)
    vis = training_rays(scene, tracks, len(pts)) if config.carve else None
    extra = view_faces(pts, training_observations(scene, tracks, len(pts))) if config.view_faces else None
    model, info = init_from_points(pts, cols, sh_degree=config.sh_degree, max_edge_ratio=config.init_max_edge or None,
                                   visibility=vis, return_info=True, extra_faces=extra)
    info.num_bounded = dropped
    on_path = near_path(model.positions, model.triangles, [scene.cameras[i].center for i in scene.train_indices])
    info.num_path_faces = int(on_path.sum())
    if config.clear_path and on_path.any() and not on_path.all():      # never an empty mesh
        model = TriangleModel(model.positions, model.triangles[~on_path], model.sh, model.opacity)
    shell = None
    if config.shell:
        views = list(scene.train_indices)
        shell = background_shell([scene.cameras[i] for i in views], [scene.images[i] for i in views], pts,
                                 sh_degree=config.sh_degree)
    model, groups = with_shell(model, shell)
    return model, groups, info
