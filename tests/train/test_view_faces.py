"""The initial mesh's view faces: each training view's 2-D Delaunay triangulation of the points
it observed, added to the tetrahedralisation's faces (tsplus_wgpu/train/init.py)."""
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial import Delaunay

from tsplus_wgpu import Camera
from tsplus_wgpu.train.config import TrainConfig
from tsplus_wgpu.train.init import init_from_points, view_faces


def _camera(centre=(0.0, 0.0, 0.0)):
    """Looking down +z from ``centre``, 64x48."""
    m = np.eye(4)
    m[:3, 3] = -np.asarray(centre, np.float64)
    return Camera(64, 48, 50.0, 50.0, 32.0, 24.0, m)


def _faces(model):
    """The model's faces as sets of their corners' positions (independent of vertex order)."""
    return {frozenset(map(tuple, model.positions[t])) for t in model.triangles}


def test_a_wall_seen_by_one_view_gives_its_image_triangulation():
    # a 5 x 4 grid on the plane z = 4 (distinct depths: the plane is slanted), seen by one camera
    gx, gy = np.meshgrid(np.linspace(-1, 1, 5), np.linspace(-0.6, 0.6, 4))
    pts = np.stack([gx.ravel(), gy.ravel(), 4.0 + 0.5 * gx.ravel()], 1)
    cam = _camera()
    uv, _ = cam.project(pts)
    expect = np.unique(np.sort(Delaunay(uv).simplices, axis=1), axis=0)
    # the wall's points among others the view did not observe: faces name rows of all points
    rows = 3 + 2 * np.arange(len(pts))
    every = np.zeros((3 + 2 * len(pts), 3))
    every[rows] = pts
    every[np.setdiff1d(np.arange(len(every)), rows)] = [0.3, 0.1, 2.0]
    np.testing.assert_array_equal(view_faces(every, [(cam, rows)]), np.sort(rows[expect], axis=1))
    got = view_faces(pts, [(cam, np.arange(len(pts)))])
    np.testing.assert_array_equal(got, expect)
    assert len(got) == 2 * 4 * 3                      # two triangles a grid cell
    assert got.dtype == np.int64 and np.all(np.diff(got, axis=1) > 0)
    # the same rows given twice, in another order, or by a second view: the same faces, once
    twice = view_faces(pts, [(cam, np.arange(len(pts))[::-1]), (cam, np.arange(len(pts)))])
    np.testing.assert_array_equal(twice, got)


def test_points_behind_a_camera_and_degenerate_views_give_no_faces():
    rng = np.random.default_rng(0)
    front = np.column_stack([rng.uniform(-1, 1, (12, 2)), rng.uniform(2, 5, 12)])
    behind = front * np.array([1.0, 1.0, -1.0])
    pts = np.concatenate([front, behind])
    got = view_faces(pts, [(_camera(), np.arange(24))])
    assert len(got) and got.max() < 12                # only the points in front are joined
    line = np.column_stack([np.linspace(-1, 1, 6), np.zeros(6), np.full(6, 3.0)])
    assert view_faces(line, [(_camera(), np.arange(6))]).shape == (0, 3)            # all on one line
    assert view_faces(pts, [(_camera(), [0, 1])]).shape == (0, 3)                  # fewer than 3 points
    assert view_faces(pts, []).shape == (0, 3)


def test_view_faces_join_the_delaunay_faces_and_are_counted():
    rng = np.random.default_rng(3)
    pts = rng.random((200, 3)) + np.array([0.0, 0.0, 3.0])
    plain, info0 = init_from_points(pts, return_info=True)
    have = _faces(plain)
    # a triangle of the cloud that is no face of its tetrahedralisation, and one that is
    new = next(f for f in ([0, k, k + 1] for k in range(1, 199)) if frozenset(map(tuple, pts[f])) not in have)
    old = np.sort(plain.triangles[0])
    old_rows = [int(np.flatnonzero(np.all(pts == plain.positions[v], axis=1))[0]) for v in old]
    extra = np.array([new, old_rows, new[::-1]], np.int64)
    model, info = init_from_points(pts, return_info=True, extra_faces=extra)
    assert info0.num_view_faces == 0 and info.num_view_faces == 1
    assert _faces(model) == have | {frozenset(map(tuple, pts[new]))}
    # duplicated points: the extra faces' rows are mapped onto the merged vertex
    dup = np.concatenate([pts, pts[new[:1]]])
    moved = np.array([[200, new[1], new[2]]], np.int64)
    assert _faces(init_from_points(dup, extra_faces=moved)) == _faces(model)
    # the long-face rule drops a long added face as it does the Delaunay ones
    far = np.concatenate([pts, [[40.0, 40.0, 40.0]]])
    long = init_from_points(far, max_edge_ratio=3, return_info=True, extra_faces=np.array([[0, 1, 200]]))[0]
    assert frozenset(map(tuple, far[[0, 1, 200]])) not in _faces(long)


def test_initial_model_adds_the_training_views_faces_only():
    from tsplus_wgpu.data.procedural import load_procedural
    from tsplus_wgpu.train.initial import initial_model, training_observations
    sc = load_procedural(size="tiny")
    cfg = TrainConfig(shell=False, clear_path=False, view_faces=True)
    on, _, info_on = initial_model(sc, cfg)
    off, _, info_off = initial_model(sc, replace(cfg, view_faces=False))
    assert not TrainConfig().view_faces                 # off by default
    assert info_off.num_view_faces == 0 and info_on.num_view_faces > 0
    assert _faces(off) < _faces(on)
    obs = training_observations(sc)
    assert [id(c) for c, _ in obs] == [id(sc.cameras[i]) for i in sorted(sc.train_indices)]
    # observations by a held-out view change nothing
    n = len(sc.points)
    offsets, views = sc.point_tracks
    lengths = np.diff(offsets) + 1
    more = np.zeros(n + 1, np.int64)
    np.cumsum(lengths, out=more[1:])
    held = np.concatenate([np.append(views[offsets[p]:offsets[p + 1]], sc.test_indices[0]) for p in range(n)])
    sc2 = replace(sc, point_tracks=(more, held.astype(np.int32)))
    again, _, info2 = initial_model(sc2, cfg)
    assert info2.num_view_faces == info_on.num_view_faces and _faces(again) == _faces(on)
    with pytest.raises(ValueError, match="point_tracks"):
        training_observations(replace(sc, point_tracks=(offsets[:3], views)))
    # no tracks: no view faces
    assert initial_model(replace(sc, point_tracks=None), cfg)[2].num_view_faces == 0
