"""The background shell (train/shell.py), the initial mesh's long-face filter (train/init.py)
and the triangle groups the topology carries through its edits (state, ops, topology)."""

from dataclasses import replace

import numpy as np
import pytest

from tsplus_wgpu.train.init import init_from_points, long_faces
from tsplus_wgpu.train.schedules import Schedule, logit_from_opacity
from tsplus_wgpu.train.shell import (SHELL, SHELL_MIN_RADIUS, SURFACE, background_shell, icosphere, shell_level,
                                     shell_radius, with_shell)
from tsplus_wgpu.train.state import VertexState
from tsplus_wgpu.train.strategy import ops
from tsplus_wgpu.types import SH_C0, Camera, TriangleModel

from scenes import look_at_camera


def _look_at(eye, target, width=40, height=30, f=30.0):
    """tests/scenes.py's look-at camera with focal length ``f`` (px)."""
    return look_at_camera(width, height, np.degrees(2 * np.arctan(0.5 * width / f)), eye, target)


@pytest.mark.parametrize("level", [0, 1, 2, 3])
def test_icosphere_counts_unit_and_outward(level):
    v, f = icosphere(level)
    assert v.shape == (10 * 4**level + 2, 3) and f.shape == (20 * 4**level, 3)
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 1.0, atol=1e-15)
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    assert (np.sum(n * v[f].mean(axis=1), axis=1) > 0).all()
    # a closed 2-manifold: every edge in exactly two faces, Euler characteristic 2
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    assert (counts == 2).all() and len(v) - len(counts) + len(f) == 2


def test_radius_and_level_rules():
    assert shell_radius(None) == SHELL_MIN_RADIUS
    pts = np.zeros((100, 3))
    pts[:, 0] = np.linspace(0, 10, 100)
    assert shell_radius(pts) == pytest.approx(2.0 * np.percentile(pts[:, 0], 99))
    cams = [_look_at((0, 0, 0), (0, 0, 1), f=f) for f in (30.0, 30.0, 30.0)]
    assert shell_level(cams) == 3                     # clamped low: 1.107 * 30 / 8 = 4.2 -> level 2
    assert shell_level([_look_at((0, 0, 0), (0, 0, 1), f=250.0)]) == 5      # 34.6 -> 5.1
    assert shell_level([_look_at((0, 0, 0), (0, 0, 1), f=1e5)]) == 6


def test_background_shell_colour_and_cut():
    """Two views from the centre looking +z, uniformly red and green: the vertices each sees
    take its colour, those both see the mean; the shell is cut to what the views see (with
    the margin), and what no view sees is gone."""
    cams = [_look_at((0, 0, 0), (0, 0, 1)), _look_at((0, 0, 0), (0, 0, 1))]
    red, green = np.zeros((30, 40, 3)), np.zeros((30, 40, 3))
    red[..., 0], green[..., 1] = 1.0, 1.0
    shell = background_shell(cams, [red, green], radius=7.0, level=3)
    assert shell is not None
    np.testing.assert_allclose(np.linalg.norm(shell.positions, axis=1), 7.0)
    full, _ = icosphere(3)
    assert 0 < shell.num_vertices < len(full)
    assert (shell.positions[:, 2] > 0).all()          # nothing behind the cameras
    colour = shell.sh[:, 0] * SH_C0 + 0.5
    u = cams[0].fx * shell.positions[:, 0] / shell.positions[:, 2] + cams[0].cx
    v = cams[0].fy * shell.positions[:, 1] / shell.positions[:, 2] + cams[0].cy
    inside = (u >= 0) & (u < 40) & (v >= 0) & (v < 30)
    assert inside.any() and (~inside).any()
    np.testing.assert_allclose(colour[inside], [[0.5, 0.5, 0.0]] * int(inside.sum()), atol=1e-12)
    np.testing.assert_allclose(colour[~inside], [[0.5, 0.5, 0.0]] * int((~inside).sum()), atol=1e-12)  # image mean
    assert np.allclose(shell.opacity, 0.9)
    # a view looking away from every vertex sees none of it
    assert background_shell([_look_at((0, 0, 0), (0, 0, 1))], [red], radius=1e-3, level=0) is not None


def test_with_shell_groups():
    base = TriangleModel(np.eye(3), [[0, 1, 2]], np.zeros((3, 4, 3)), np.full(3, 0.28))
    shell = TriangleModel(np.eye(3) * 5, [[0, 1, 2], [2, 1, 0]], np.ones((3, 1, 3)), np.full(3, 0.9))
    merged, groups = with_shell(base, shell)
    assert merged.num_vertices == 6 and merged.sh.shape == (6, 4, 3)
    np.testing.assert_array_equal(merged.triangles, [[0, 1, 2], [3, 4, 5], [5, 4, 3]])
    np.testing.assert_array_equal(groups, [SURFACE, SHELL, SHELL])
    assert (merged.sh[3:, 1:] == 0).all() and (merged.sh[3:, 0] == 1).all()
    same, g = with_shell(base, None)
    assert same is base and (g == SURFACE).all()


def test_long_faces_drop_the_span_across_free_space():
    """A dense grid on a plane and one far point: every face to the far point spans free space
    and is dropped; faces within the grid are kept; ratio 0 keeps everything."""
    g = np.stack(np.meshgrid(np.arange(10.0), np.arange(10.0)), -1).reshape(-1, 2)
    pts = np.concatenate([np.c_[g, np.zeros(len(g))] + 1e-3 * np.random.default_rng(0).normal(size=(100, 3)),
                          [[4.5, 4.5, 30.0]]])
    model, info = init_from_points(pts, sh_degree=0, return_info=True, max_edge_ratio=3.0)
    assert info.num_long_faces > 0
    far = np.flatnonzero(model.positions[:, 2] > 10)
    assert len(far) == 0 or not np.isin(model.triangles, far).any()
    edge = np.max([np.linalg.norm(model.positions[model.triangles[:, i]] - model.positions[model.triangles[:, (i + 1) % 3]],
                                  axis=1) for i in range(3)], axis=0)
    assert edge.max() < 10.0
    all_faces, info0 = init_from_points(pts, sh_degree=0, return_info=True)
    assert info0.num_long_faces == 0 and all_faces.num_triangles > model.num_triangles
    assert np.isin(all_faces.triangles, np.flatnonzero(all_faces.positions[:, 2] > 10)).any()
    mask = long_faces(model.positions, model.triangles, 3.0)
    assert not mask.any()


def _state(groups, opacity):
    pos = np.array([[0, 0, 5], [1, 0, 5], [0, 1, 5], [1, 1, 5], [5, 5, 30], [8, 5, 30], [5, 8, 30]], float)
    tris = np.array([[0, 1, 2], [1, 3, 2], [4, 5, 6]])
    sh = np.zeros((len(pos), 1, 3))
    return VertexState.from_model(pos, tris, sh, logit_from_opacity(np.asarray(opacity, float), 0.0),
                                  groups=np.asarray(groups, np.int8))


def test_groups_follow_prune_and_densify():
    st = _state([SURFACE, SURFACE, SHELL], [0.5] * 7)
    pruned = ops.prune(st, np.array([True, False, False]))
    np.testing.assert_array_equal(pruned.groups, [SURFACE, SHELL])
    split = ops.densify(st, np.array([2, 0]), 0.0)
    np.testing.assert_array_equal(split.groups, [SURFACE] + [SHELL] * 4 + [SURFACE] * 4)
    # the largest-by-area part never picks the shell, the weighted draw may
    areas = ops.triangle_areas(st.positions, st.triangles)
    assert np.argmax(areas) == 2
    rng = np.random.default_rng(0)
    chosen = ops.choose_split(np.zeros(3), areas, 1, 3, rng, largest_from=st.group_of() != SHELL)
    assert 2 not in chosen and set(chosen) == {0, 1}
    chosen = ops.choose_split(np.array([0.0, 0.0, 1.0]), areas, 1, 0, rng, largest_from=st.group_of() != SHELL)
    np.testing.assert_array_equal(chosen, [2])


def test_prune_keeps_the_shell():
    """At the hard prune every triangle is transparent and unseen: the surface goes, the shell
    stays; without groups everything but the heaviest triangle would go."""
    from tsplus_wgpu.train.strategy import TopologyStrategy
    sched = Schedule(total=30000)
    it = 5000
    assert sched.is_hard_prune_step(it)
    cams = [_look_at((0.5, 0.5, 0), (0.5, 0.5, 5))]
    s = TopologyStrategy(sched)
    s.seen = {0}
    st = _state([SURFACE, SURFACE, SHELL], [0.05] * 7)
    st = replace(st, max_weight=np.array([0.05, 0.05, 0.2], np.float32))   # the shell seen through the surface
    rec = {}
    drop, _ = s.prune_mask(st, it, [0], cams, rec)
    np.testing.assert_array_equal(drop, [True, True, False])
    assert rec["shell_kept"] == 1 and rec["shell_hidden"] == 0
    # a shell triangle no view saw (weight <= 1/255) is behind the surfaces: it goes from the hard prune on
    hidden = replace(st, max_weight=np.array([0.05, 0.05, 0.003], np.float32))
    rec = {}
    drop, _ = s.prune_mask(hidden, it, [0], cams, rec)
    assert drop[2]                  # (the heaviest surface triangle stays: never an empty model)
    assert rec["shell_hidden"] == 1 and rec["shell_kept"] == 0
    # ... but not one that no view can show: nothing says it is hidden (the backdrop of other viewpoints)
    away = [_look_at((0.5, 0.5, 0), (0.5, 0.5, -5))]
    rec = {}
    drop, _ = s.prune_mask(hidden, it, [0], away, rec)
    assert not drop[2] and rec["shell_hidden"] == 0
    before = sched.floor_start() - sched.topology_every()
    assert sched.is_prune_step(before)
    s.seen = {0}
    drop, _ = s.prune_mask(hidden, before, [0], cams, {})
    assert not drop[2]
    st = _state([SURFACE, SURFACE, SURFACE], [0.05] * 7)
    drop, _ = s.prune_mask(st, it, [0], cams, {})
    assert drop.sum() == 2


def test_trainer_starts_with_the_shell_and_checkpoints_its_groups(renderer, tmp_path):
    """The default initial mesh has shell triangles (marked) behind the filtered Delaunay mesh; a
    checkpoint stores the groups and a resume gets them back; --shell off has none."""
    from tsplus_wgpu.data.procedural import load_procedural
    from tsplus_wgpu.train.trainer import TrainConfig, Trainer
    tiny = load_procedural("tiny")
    cfg = TrainConfig(iterations=4, quick=True, topology=False)
    t = Trainer(tiny, cfg, renderer=renderer)
    shell = t.groups == SHELL
    assert shell.any() and (~shell).any()
    # shell triangles are the last ones, on a sphere of >= 5 camera radii around the frame origin
    assert shell[-int(shell.sum()):].all()
    pos = t.read_state().positions
    r = np.linalg.norm(pos[t.triangles_host[shell].ravel()], axis=1)
    assert r.min() >= SHELL_MIN_RADIUS * (1 - 1e-5)
    t.step()
    t.save_checkpoint(tmp_path / "c.npz")
    back = Trainer.resume(tmp_path / "c.npz", tiny, renderer=renderer)
    np.testing.assert_array_equal(back.groups, t.groups)
    assert back.read_state().groups.dtype == np.int8
    off = Trainer(tiny, TrainConfig(iterations=4, quick=True, topology=False, shell=False), renderer=renderer)
    assert not (off.read_state().group_of() == SHELL).any() and off.m < t.m


def test_in_views_and_the_backdrop_beyond_them():
    """A triangle counts as shown when a vertex or its centroid projects inside the image in
    front of the camera; the final cleanup keeps the shell triangles no training view shows."""
    from tsplus_wgpu.train.shell import beyond_views
    cam = _look_at((0, 0, 0), (0, 0, 10))          # 40x30 px, f 30: x/z within +-0.667 is inside
    pos = np.array([[0, 0, 5], [1, 0, 5], [0, 1, 5],                  # 0: inside
                    [4.0, -0.5, 5], [4.2, 0.5, 5], [-4.0, 0.0, 5],    # 1: vertices outside, centroid inside
                    [9, 9, 5], [10, 9, 5], [9, 10, 5],                # 2: outside
                    [0, 0, -5], [0.1, 0, -5], [0, 0.1, -5]], float)   # 3: behind the camera
    tris = np.arange(12).reshape(4, 3)
    np.testing.assert_array_equal(ops.in_views(pos, tris, [cam]), [True, True, False, False])
    back = _look_at((0, 0, 0), (0, 0, -10))
    np.testing.assert_array_equal(ops.in_views(pos, tris, [cam, back]), [True, True, False, True])
    groups = np.array([SURFACE, SHELL, SHELL, SURFACE], np.int8)
    np.testing.assert_array_equal(beyond_views(groups, pos, tris, [cam], 0.01), [False, False, True, False])
    assert not beyond_views(None, pos, tris, [cam], 0.01).any()


def test_final_prune_off_keeps_every_triangle(renderer):
    """--final-prune off exports every triangle; on (the paper's cleanup) drops the ones no
    training view sees with a weight above 0.5 (after 3 steps at opacity ~0.28: most)."""
    from tsplus_wgpu.data.procedural import load_procedural
    from tsplus_wgpu.train.trainer import TrainConfig, Trainer
    tiny = load_procedural("tiny")
    kept = {}
    for on in (True, False):
        t = Trainer(tiny, TrainConfig(iterations=3, quick=True, topology=False, final_prune=on, fill_holes=False,
                                      remove_shards=False, color_detail=False, log_every=0),
                    renderer=renderer)
        t.train(progress=False, checkpoint_at_end=False)
        kept[on] = len(t.final_mesh()[1])
        total = t.m
    assert kept[False] == total and kept[True] < total


def test_backdrop_fills_every_hole_of_the_training_views(renderer):
    """Without a trained shell and with the paper's cleanup after 3 steps most triangles go and
    the training views show holes; --fill-holes adds a fresh shell's triangles seen through them, so the exported mesh
    draws every pixel centre of every training view (and off leaves the holes)."""
    from tsplus_wgpu import MeshRenderer
    from tsplus_wgpu.data.procedural import load_procedural
    from tsplus_wgpu.train.trainer import TrainConfig, Trainer
    tiny = load_procedural("tiny")
    mr = MeshRenderer(renderer.ctx)
    near = tiny.frame().near_world()
    cover, meshes = {}, {}
    for fill in (False, True):
        # no shard removal: its error test counts the fill's pixels, so the two meshes could differ by a shard
        t = Trainer(tiny, TrainConfig(iterations=3, quick=True, topology=False, final_prune=True, fill_holes=fill,
                                      shell=False, mesh_colors="dc", remove_shards=False, log_every=0),
                    renderer=renderer)
        t.train(progress=False, checkpoint_at_end=False)
        pos, tri, col = meshes[fill] = t.final_mesh()
        cover[fill] = [mr.render((pos, tri, col), tiny.cameras[v], near=near).coverage.mean()
                       for v in tiny.train_indices]
        filled = t.final_info["filled_triangles"]
        assert (filled > 0) == fill
    assert min(cover[False]) < 0.95 and min(cover[True]) == 1.0
    n_off, m_off = len(meshes[False][0]), len(meshes[False][1])
    np.testing.assert_array_equal(meshes[True][1][:m_off], meshes[False][1])    # the mesh itself unchanged
    np.testing.assert_array_equal(meshes[True][0][:n_off], meshes[False][0])


def test_a_shard_across_the_views_is_removed(renderer):
    """A large magenta triangle between the first camera and the scene (a shard: it draws what
    no photo shows) is removed at the end with --remove-shards on (what is behind it, and the
    fill, take its pixels: the training views get closer), and kept with off. SH DC colours
    here: the colour fit would paint a shard that only one view sees with that view's mean
    colour; what the fit leaves to find_shards is measured on the real scenes."""
    from tsplus_wgpu import MeshRenderer, TriangleModel
    from tsplus_wgpu.data.procedural import load_procedural
    from tsplus_wgpu.train.initial import initial_model
    from tsplus_wgpu.train.trainer import TrainConfig, Trainer
    tiny = load_procedural("tiny")
    cfg = dict(iterations=3, quick=True, topology=False, log_every=0, mesh_colors="dc")
    model, groups, _ = initial_model(tiny, TrainConfig(**cfg))
    cam = tiny.cameras[tiny.train_indices[0]]
    c, centre = cam.center, np.zeros(3)
    mid = c + 0.4 * (centre - c)
    d = np.linalg.norm(centre - c)
    a = np.cross(centre - c, [0.0, 0.0, 1.0])
    a /= np.linalg.norm(a)
    b = np.cross(centre - c, a)
    b /= np.linalg.norm(b)
    shard = np.stack([mid + 0.3 * d * a, mid - 0.3 * d * a + 0.2 * d * b, mid - 0.2 * d * b])
    n = model.num_vertices
    sh = np.concatenate([model.sh, np.zeros((3,) + model.sh.shape[1:])])
    sh[n:, 0] = (np.array([1.0, 0.0, 1.0]) - 0.5) / 0.28209479177387814
    big = TriangleModel(np.concatenate([model.positions, shard]), np.concatenate([model.triangles, [[n, n + 1, n + 2]]]),
                        sh, np.concatenate([model.opacity, np.full(3, 0.99)]))
    big_groups = np.concatenate([groups, [0]]).astype(np.int8)
    mr = MeshRenderer(renderer.ctx)
    near = tiny.frame().near_world()
    err, removed = {}, {}
    for on in (False, True):
        t = Trainer(tiny, TrainConfig(**cfg, remove_shards=on), renderer=renderer, model=big, groups=big_groups)
        t.train(progress=False, checkpoint_at_end=False)
        pos, tri, col = t.final_mesh()
        removed[on] = t.final_info["shards"]
        err[on] = np.mean([np.mean((mr.render((pos, tri, col), tiny.cameras[v], near=near).image - tiny.images[v]) ** 2)
                           for v in tiny.train_indices])
        # the shard's corners (moved a little by 3 steps) are in the mesh exactly when it is kept
        gap = np.min(np.linalg.norm(pos[:, None, :] - shard[None], axis=2), axis=0).max()
        assert (gap < 0.05 * d) == (not on), (on, gap)
    assert removed[False] == 0 and removed[True] >= 1
    assert err[True] < 0.9 * err[False]


def test_fill_hidden_covers_what_the_shell_lost_behind_the_surfaces(renderer):
    """The trained shell's triangles hidden behind the surfaces in every training view are
    deleted during training (here by hand, after 3 steps). A viewpoint beyond the surfaces then
    sees holes in the backdrop. The fill of --fill-hidden (the fresh shell, FILL_BEHIND beyond
    the trained one, seen through the trained shell's holes) covers them; the fill of the
    training views' holes alone does not: it draws whatever a whole fresh shell draws there."""
    from tsplus_wgpu.data.procedural import load_procedural
    from tsplus_wgpu.render.mesh_fit import triangle_ids
    from tsplus_wgpu.train.final import FILL_BEHIND, backdrop_fill
    from tsplus_wgpu.train.shell import shell_radius
    from tsplus_wgpu.train.trainer import TrainConfig, Trainer
    tiny = load_procedural("tiny")
    t = Trainer(tiny, TrainConfig(iterations=3, quick=True, topology=False, log_every=0), renderer=renderer)
    t.train(progress=False, checkpoint_at_end=False)
    pos, tri, near = t.positions_frame().astype(np.float64), t.triangles_host, t.config.near
    cams = [t.scene.cameras[v] for v in t.train_views]
    seen = np.zeros(len(tri), bool)
    for cam in cams:
        ids = triangle_ids(t.mesh_renderer, pos, tri, cam, near)
        seen[ids[ids >= 0]] = True
    shell = np.asarray(t.groups) == SHELL
    hidden = shell & ~seen & ops.in_views(pos, tri, cams, near)
    assert hidden.sum() > 100
    kept = tri[~hidden]
    # a camera beyond the surfaces, looking at the middle of the lost part of the shell
    centres = pos[tri[hidden]].mean(1)
    d = centres.mean(0) / np.linalg.norm(centres.mean(0))
    eye = 1.5 * d
    z = d
    x = np.cross(z, [0.0, 0.0, 1.0] if abs(d[2]) < 0.9 else [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    m = np.eye(4)
    m[:3, :3] = np.stack([x, np.cross(z, x), z])
    m[:3, 3] = -m[:3, :3] @ eye
    novel = Camera(48, 36, 30.0, 30.0, 24.0, 18.0, m)
    cover = {}
    for name, occluders in (("holes", None), ("hidden", shell[~hidden])):
        fpos, ftri, fcol = backdrop_fill(t, pos, kept, occluders)
        allpos = np.concatenate([pos, fpos])
        alltri = np.concatenate([kept, ftri + len(pos)])
        cover[name] = float((triangle_ids(t.mesh_renderer, allpos, alltri, novel, near) >= 0).mean())
        if name == "hidden":
            r = np.linalg.norm(fpos, axis=1)
            np.testing.assert_allclose(r, (1 + FILL_BEHIND) * shell_radius(t.scene.points), rtol=1e-9)
            assert len(ftri) >= 0.5 * hidden.sum() and np.all(np.isfinite(fcol))
    # the novel view sees past the training views' backdrop too (beyond their margin), so "all" is
    # what a whole fresh shell draws there
    whole = background_shell(cams, [t.scene.images[v] for v in t.train_views], t.scene.points)
    cover["whole shell"] = float((triangle_ids(t.mesh_renderer, whole.positions, whole.triangles, novel, near) >= 0).mean())
    assert cover["holes"] < cover["whole shell"] - 0.05 and cover["hidden"] >= cover["whole shell"], cover


def test_the_early_prune_takes_transparent_surface_triangles_only():
    """Before the first prune step a quick run's densify step deletes the surface triangles whose
    min vertex opacity is at or below the threshold: not the shell's, not by weight, and the running
    max weight is not reset."""
    from tsplus_wgpu.train.strategy import TopologyStrategy
    sched = Schedule(total=1700, quick=True, views=67, topology_epochs=3, early_prune=True)
    it = next(i for i in range(1, 1701) if sched.is_early_prune_step(i))
    cams = [_look_at((0.5, 0.5, 0), (0.5, 0.5, 5))]
    s = TopologyStrategy(sched)
    s.densify_stopped, s.read_l1_window = "off in this test", lambda it: None      # no device ring here
    thr = sched.prune_threshold(it)
    # vertex 3 (triangle 1's own corner) transparent, the shell's as well; triangle 0 stays at 0.28
    st = _state([SURFACE, SURFACE, SHELL], [0.28, 0.28, 0.28, thr - 1e-3, 0.01, 0.01, 0.01])
    st = replace(st, max_weight=np.array([0.02, 0.3, 0.0], np.float32))   # triangle 0 too light for the weight test
    out = s.edit(st, it, [0], cams)
    rec = s.events[-1]
    assert rec["pruned_early"] == 1 and "pruned_weight" not in rec and "pruned_opacity" not in rec
    np.testing.assert_array_equal(out.groups, [SURFACE, SHELL])
    np.testing.assert_array_equal(out.max_weight, np.float32([0.02, 0.0]))  # kept, not reset
    # just above the threshold nothing goes
    above = _state([SURFACE, SURFACE, SHELL], [0.28, 0.28, 0.28, thr + 1e-3, 0.01, 0.01, 0.01])
    assert not s.early_prune_mask(above, it, {}).any()
    # without the switch the same step only densifies
    plain = TopologyStrategy(Schedule(total=1700, quick=True, views=67, topology_epochs=3))
    plain.densify_stopped, plain.read_l1_window = "off in this test", lambda it: None
    assert plain.edit(st, it, [0], cams).m == 3 and "pruned_early" not in plain.events[-1]
