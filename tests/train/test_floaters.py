"""Floaters on the cameras' path (train/floaters.py): the path graph, the point-to-path distance
against a dense float64 twin, the triangles found near it (pierced ones included, none beyond the
radius, the same at any world scale and offset), and the end of training removing one."""

import numpy as np
import pytest

from tsplus_wgpu.train.floaters import PATH_RADIUS, camera_path, near_path, path_distance, path_floaters

#: ten cameras 1 apart along x, and one misregistered 100 away
LINE = np.concatenate([np.column_stack([np.arange(10.0), np.zeros(10), np.zeros(10)]), [[4.0, 100.0, 0.0]]])


def test_the_path_links_neighbours_and_not_a_far_camera():
    links, spacing = camera_path(LINE)
    assert spacing == 1.0
    assert {tuple(x) for x in links} == {(i, i + 1) for i in range(9)} | {(0, 2), (7, 9)}   # the ends: 2 on one side
    assert not (links == 10).any()                          # 100 away: over 3 spacings, never linked
    assert camera_path(LINE[:1])[1] == 0.0 and len(camera_path(LINE[:1])[0]) == 0


def test_path_distance_matches_a_dense_twin():
    rng = np.random.default_rng(0)
    links, _ = camera_path(LINE)
    pts = rng.uniform([-2, -3, -3], [11, 3, 3], size=(300, 3))
    t = np.linspace(0.0, 1.0, 20001)
    dense = np.concatenate([LINE[a] + t[:, None] * (LINE[b] - LINE[a]) for a, b in links] + [LINE])
    twin = np.array([np.linalg.norm(dense - p, axis=1).min() for p in pts])
    got = path_distance(pts, LINE, links)
    np.testing.assert_allclose(got, twin, atol=1e-4)        # the twin's samples are 5e-5 apart at most
    assert np.all(got <= twin + 1e-12)                      # exact: never above a sampled distance


def test_the_lower_bound_drops_only_what_is_beyond_the_limit(monkeypatch):
    """``may_reach`` keeps every point the exact distance puts within the limit (points scattered
    about the path, many just past it), and drops most of those far from it; ``near_path`` with it
    finds the same triangles as without it."""
    import tsplus_wgpu.train.floaters as fl
    rng = np.random.default_rng(1)
    links, _ = camera_path(LINE)
    pts = rng.uniform([-3, -3, -3], [12, 3, 3], size=(20000, 3))
    limit = rng.uniform(0.1, 1.5, len(pts))
    exact = path_distance(pts, LINE, links) < limit
    keep = fl.may_reach(pts, LINE, links, limit)
    assert exact.sum() > 500 and np.all(keep[exact]) and (~keep).sum() > 0.5 * (~exact).sum()
    assert (np.abs(path_distance(pts, LINE, links) - limit) < 0.02).sum() > 50   # some right at the limit
    cen = np.repeat(pts[:3000], 3, axis=0) + rng.normal(0, 0.2, (9000, 3))
    tris = np.arange(9000).reshape(-1, 3)
    with_bound = near_path(cen, tris, LINE)
    monkeypatch.setattr(fl, "may_reach", lambda p, *a: np.ones(len(p), bool))
    np.testing.assert_array_equal(with_bound, near_path(cen, tris, LINE))
    assert 30 < with_bound.sum() < 2900


def test_near_path_finds_pierced_and_close_triangles_and_nothing_beyond():
    r = PATH_RADIUS * 1.0
    tris = np.arange(12).reshape(4, 3)
    pos = np.array([
        [4.5, -5.0, -5.0], [4.5, 5.0, -5.0], [4.5, 0.0, 5.0],          # 10 wide, pierced by the path at x = 4.5
        [2.0, 0.3 * r, 0.1], [2.0, 3.0, 0.0], [2.5, 3.0, 1.0],          # a corner 0.3 r from the path
        [2.0, 1.05 * r, -1.0], [2.0, 1.05 * r, 1.0], [3.0, 1.05 * r, 0.0],   # wholly 1.05 r away
        [7.0, 0.7 * r, -4.0], [7.0, 0.7 * r, 4.0], [7.5, 4.0, 0.0],     # an edge passes 0.7 r away, corners far
    ])
    expect = [True, True, False, True]
    np.testing.assert_array_equal(near_path(pos, tris, LINE), expect)
    # units: a world scaled by 1000 and shifted gives the same triangles
    shift = np.array([1e4, -3e3, 7e2])
    np.testing.assert_array_equal(near_path(1000 * pos + shift, tris, 1000 * LINE + shift), expect)


@pytest.mark.parametrize("scale", [1.0, 1e-3])
def test_only_surface_triangles_count(scale):
    class Cam:
        def __init__(self, c):
            self.center = np.asarray(c, np.float64)
    cams = [Cam(scale * c) for c in LINE]
    pos = scale * np.array([[4.5, -1, -1], [4.5, 1, -1], [4.5, 0, 1]] * 2, np.float64)
    tris = np.array([[0, 1, 2], [3, 4, 5]])
    np.testing.assert_array_equal(path_floaters(pos, tris, np.array([0, 1], np.int8), cams), [True, False])
    np.testing.assert_array_equal(path_floaters(pos, tris, None, cams), [True, True])


def test_the_end_of_training_removes_a_floater_on_the_path(renderer):
    """A small triangle just beside the path between two neighbouring training cameras of the
    tiny scene, facing them: --remove-shards on removes it (counted as a floater), off keeps it;
    nothing else of the scene is near the path."""
    from tsplus_wgpu.train.initial import initial_model
    from tsplus_wgpu.train.trainer import TrainConfig, Trainer
    from tsplus_wgpu.data.procedural import load_procedural
    from tsplus_wgpu.types import TriangleModel
    tiny = load_procedural("tiny")
    cfg = dict(iterations=2, quick=True, topology=False, log_every=0, mesh_colors="dc", color_detail=False)
    model, groups, _ = initial_model(tiny, TrainConfig(**cfg))          # --clear-path on: nothing on the path
    centres = np.array([tiny.cameras[v].center for v in tiny.train_indices])
    links, spacing = camera_path(centres)
    assert not near_path(model.positions, model.triangles, centres).any()
    a, b = centres[links[0, 0]], centres[links[0, 1]]
    mid = 0.5 * (a + b)
    u = (b - a) / np.linalg.norm(b - a)
    w = np.cross(u, [0.0, 0.0, 1.0])
    w /= np.linalg.norm(w)
    s = 0.1 * spacing
    floater = np.stack([mid + s * w, mid - s * w, mid + s * np.cross(u, w)])
    n = model.num_vertices
    sh = np.concatenate([model.sh, np.zeros((3,) + model.sh.shape[1:])])
    big = TriangleModel(np.concatenate([model.positions, floater]), np.concatenate([model.triangles, [[n, n + 1, n + 2]]]),
                        sh, np.concatenate([model.opacity, np.full(3, 0.99)]))
    big_groups = np.concatenate([groups, [0]]).astype(np.int8)
    for on in (False, True):
        t = Trainer(tiny, TrainConfig(**cfg, remove_shards=on), renderer=renderer, model=big, groups=big_groups)
        t.train(progress=False, checkpoint_at_end=False)
        pos, _, _ = t.final_mesh()
        # the floater's corners (moved a little by 2 steps) are in the mesh exactly when it is kept
        gap = np.min(np.linalg.norm(pos[:, None, :] - floater[None], axis=2), axis=0).max()
        assert (gap < 0.05 * spacing) == (not on), (on, gap)
        assert t.final_info["floaters"] == (1 if on else 0)


def test_the_initial_mesh_leaves_the_path_clear():
    """The tiny room's Delaunay mesh spans the space the cameras moved through: --clear-path on
    (default) drops exactly those faces, off keeps them; the count is reported either way."""
    from tsplus_wgpu.data.procedural import load_procedural
    from tsplus_wgpu.train.config import TrainConfig
    from tsplus_wgpu.train.initial import initial_model
    tiny = load_procedural("tiny")
    centres = [tiny.cameras[v].center for v in tiny.train_indices]
    base = dict(iterations=2, quick=True, shell=False)
    off, _, info_off = initial_model(tiny, TrainConfig(**base, clear_path=False))
    on, _, info_on = initial_model(tiny, TrainConfig(**base))
    hit = near_path(off.positions, off.triangles, centres)
    assert info_off.num_path_faces == info_on.num_path_faces == int(hit.sum()) > 0
    np.testing.assert_array_equal(on.triangles, off.triangles[~hit])
    np.testing.assert_array_equal(on.positions, off.positions)
