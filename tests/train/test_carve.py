"""Visibility carving (tsplus_wgpu/train/carve.py): the vectorised walk through the
tetrahedralisation against a brute-force segment/triangle test, and its use in the initial mesh."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial import Delaunay

from tsplus_wgpu.train.carve import crossing_counts, tet_faces
from tsplus_wgpu.train.config import TrainConfig
from tsplus_wgpu.train.init import init_from_points
from tsplus_wgpu.train.initial import initial_model, training_rays


def _brute_counts(points, faces, ray_pt, origins, margin):
    """Crossings of every segment point -> origin with every face (float64 Moller-Trumbore),
    counted where the segment parameter from the point is in [margin, 1)."""
    a, b, c = (points[faces[:, k]] for k in range(3))
    e1, e2 = b - a, c - a
    counts = np.zeros(len(faces), np.int64)
    for p_idx, o in zip(ray_pt, origins):
        p = points[p_idx]
        d = o - p
        h = np.cross(np.broadcast_to(d, e2.shape), e2)
        det = np.einsum("ij,ij->i", e1, h)
        ok = np.abs(det) > 1e-14
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        sv = p - a
        u = inv * np.einsum("ij,ij->i", sv, h)
        q = np.cross(sv, e1)
        v = inv * (q @ d)
        t = inv * np.einsum("ij,ij->i", e2, q)
        hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= margin) & (t < 1)
        counts += hit
    return counts


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_walk_counts_equal_brute_force_crossings(seed):
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-1, 1, (70, 3))
    tri = Delaunay(pts)
    # cameras outside the hull and inside it
    cams = np.concatenate([rng.normal(size=(4, 3)) * 0 + rng.choice([-1, 1], (4, 3)) * 3.0,
                           rng.uniform(-0.5, 0.5, (3, 3))])
    ray_pt = rng.integers(0, len(pts), 300)
    origins = cams[rng.integers(0, len(cams), 300)]
    margin = 0.05
    faces, counts, info = crossing_counts(pts, tri.simplices, tri.neighbors, tri.transform, ray_pt, origins,
                                          margin=margin)
    ref = _brute_counts(pts, faces, ray_pt, origins, margin)
    assert info["unfinished"] == 0
    assert counts.sum() > 100              # the test exercises many crossings
    np.testing.assert_array_equal(counts, ref)


def test_tet_faces_are_the_init_faces_and_opposite_their_vertex():
    rng = np.random.default_rng(3)
    tri = Delaunay(rng.uniform(size=(40, 3)))
    faces, tet_face = tet_faces(tri.simplices)
    assert len(np.unique(faces, axis=0)) == len(faces)
    for t in range(0, len(tri.simplices), 7):
        for i in range(4):
            assert tri.simplices[t, i] not in faces[tet_face[t, i]]
            nb = tri.neighbors[t, i]
            if nb >= 0:             # the neighbour across that face shares it
                assert tet_face[t, i] in tet_face[nb]


def _box_scene():
    """Points on the inside of a box's floor and back wall, cameras in front looking in: the
    space between cameras and surfaces is empty."""
    rng = np.random.default_rng(5)
    floor = np.c_[rng.uniform(-1, 1, 300), np.full(300, -1.0), rng.uniform(-1, 1, 300)]
    wall = np.c_[rng.uniform(-1, 1, 300), rng.uniform(-1, 1, 300), np.full(300, 1.0)]
    pts = np.concatenate([floor, wall]) + rng.normal(scale=1e-3, size=(600, 3))
    cams = np.c_[np.linspace(-0.8, 0.8, 6), np.full(6, 0.2), np.full(6, -3.0)]
    return pts, cams


def test_carving_removes_free_space_faces_and_keeps_the_surfaces():
    pts, cams = _box_scene()
    ray_pt = np.repeat(np.arange(len(pts)), len(cams))
    origins = np.tile(cams, (len(pts), 1))
    plain, pinfo = init_from_points(pts, return_info=True)
    carved, cinfo = init_from_points(pts, return_info=True, visibility=(ray_pt, origins))
    assert cinfo.num_carved_faces > 0.3 * len(plain.triangles)
    assert len(carved.triangles) == len(plain.triangles) - cinfo.num_carved_faces - (
        cinfo.num_degenerate_faces - pinfo.num_degenerate_faces)
    # the hull of floor and wall is a wedge whose inside the cameras look through: faces joining
    # floor and wall points span it; carving removes nearly all of those (the rest: thin ones along the corner)
    def spanning(m):
        on_floor = m.positions[m.triangles][..., 1] < -0.99
        on_wall = m.positions[m.triangles][..., 2] > 0.99
        return np.count_nonzero(~np.all(on_floor, axis=1) & ~np.all(on_wall, axis=1))
    assert spanning(plain) > 1000
    assert spanning(carved) < 0.15 * spanning(plain)
    # most surface faces survive: faces with all three vertices on the floor
    on_floor = lambda m: np.count_nonzero(np.all(m.positions[m.triangles][..., 1] < -0.99, axis=1))
    assert on_floor(carved) > 0.8 * on_floor(plain)


def test_no_rays_no_carving_and_duplicates_share_tracks():
    pts, cams = _box_scene()
    m0 = init_from_points(pts)
    m1 = init_from_points(pts, visibility=(np.zeros(0, np.int64), np.zeros((0, 3))))
    np.testing.assert_array_equal(m0.triangles, m1.triangles)
    # a duplicated point's observations count for the merged vertex
    dup = np.concatenate([pts, pts[:50]])
    ray_pt = np.repeat(np.arange(len(pts), len(dup)), len(cams))
    origins = np.tile(cams, (50, 1))
    ref = init_from_points(pts, visibility=(np.repeat(np.arange(50), len(cams)), origins))
    got = init_from_points(dup, visibility=(ray_pt, origins))
    np.testing.assert_array_equal(ref.triangles, got.triangles)


def test_training_rays_use_training_views_only():
    from tsplus_wgpu.data.procedural import load_procedural
    sc = load_procedural(size="tiny")
    n = len(sc.points)
    views = np.array([sc.test_indices[0], sc.train_indices[0]] * n, np.int32)
    sc = replace(sc, point_tracks=(np.arange(0, 2 * n + 1, 2, dtype=np.int64), views))
    ray_pt, origins = training_rays(sc)
    np.testing.assert_array_equal(ray_pt, np.arange(n))
    np.testing.assert_allclose(origins, np.tile(sc.cameras[sc.train_indices[0]].center, (n, 1)))
    on = initial_model(sc, TrainConfig(carve=True, shell=False))[2]
    off = initial_model(sc, TrainConfig(carve=False, shell=False))[2]
    assert off.num_carved_faces == 0 and on.num_carved_faces > 0
    with pytest.raises(ValueError, match="point_tracks"):
        training_rays(replace(sc, point_tracks=(np.arange(3, dtype=np.int64), views[:2])))


def test_initial_points_are_bounded_multi_view_first_the_same_for_every_seed():
    from tsplus_wgpu.data.procedural import load_procedural
    from tsplus_wgpu.train.initial import bounded_points
    from tsplus_wgpu.train.strategy.cap import initial_points_bound, vertex_cap
    sc = load_procedural(size="tiny")
    n = len(sc.points)
    tr, te = sc.train_indices, sc.test_indices[0]
    # even points: 3 training views; odd points: 2 training views and the held-out one (3 in all)
    views = np.array([[tr[0], tr[1], tr[2]] if k % 2 == 0 else [tr[0], tr[1], te] for k in range(n)], np.int32)
    sc = replace(sc, point_tracks=(np.arange(0, 3 * n + 1, 3, dtype=np.int64), views.ravel()))
    cams = [sc.cameras[i] for i in tr]
    cfg = TrainConfig(shell=False, init_points_share=0.05)
    most = initial_points_bound(cfg, cams)
    assert most == int(np.ceil(0.05 * vertex_cap(cfg, cams).vertices)) and 3 <= most < (n + 1) // 2
    pts, cols, tracks, dropped = bounded_points(sc, cfg)
    assert len(pts) == most and dropped == n - most
    kept = np.array([int(np.flatnonzero(np.all(sc.points == p, axis=1))[0]) for p in pts])
    assert np.all(np.diff(kept) > 0) and np.all(kept % 2 == 0)      # in order; held-out views do not count
    np.testing.assert_array_equal(cols, sc.point_colors[kept])
    np.testing.assert_array_equal(tracks[1], views[kept].ravel())
    assert kept.max() > 0.8 * n and kept.min() < 0.2 * n                # a random choice, not the first ones
    again = bounded_points(sc, replace(cfg, seed=5))
    np.testing.assert_array_equal(again[0], pts)                        # the view-order seed does not change it
    info = initial_model(sc, cfg)[2]
    assert info.num_input == most and info.num_bounded == n - most
    # over the multi-view points: all of them, then the others
    cfg2 = TrainConfig(shell=False, init_points_share=0.05 * (0.75 * n) / most)
    pts2 = bounded_points(sc, cfg2)[0]
    kept2 = np.array([int(np.flatnonzero(np.all(sc.points == p, axis=1))[0]) for p in pts2])
    assert np.count_nonzero(kept2 % 2 == 0) == (n + 1) // 2 and len(kept2) > (n + 1) // 2
    # share 0, or a bound over the points: all of them, as they are
    for c in (TrainConfig(shell=False, init_points_share=0.0), TrainConfig(shell=False)):
        got = bounded_points(sc, c)
        assert got[0] is sc.points and got[3] == 0
