"""Where an exported mesh stands (`tsplus export --origin ground --camera-height H`): the middle
of what the cameras look at, the ground under it, the cameras' height above it, and the frame
the export writes, on scenes whose answer is known."""

import json

import numpy as np
import pytest
import trimesh
from scenes import merge_meshes as _join

from tsplus_wgpu.apps.placement import PlacementError, engine_frame, find_placement, flat_middle
from tsplus_wgpu.apps.runs import load_run
from tsplus_wgpu.cli.main import main
from tsplus_wgpu.io.export import export, file_frame


def _floor(rng, height, half=3.0, n=20, rough=0.01, center=(0.0, 0.0)):
    """A rough square floor of ``2 n^2`` triangles at ``height`` (z up), its vertices jittered."""
    u = np.linspace(-half, half, n + 1)
    x, y = np.meshgrid(u + center[0], u + center[1], indexing="ij")
    z = height + rng.normal(0.0, rough, x.shape)
    v = np.stack([x, y, z], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a = (i * (n + 1) + j).ravel()
    f = np.concatenate([np.stack([a, a + n + 1, a + 1], 1), np.stack([a + 1, a + n + 1, a + n + 2], 1)])
    return v, f


def _wall(rng, x0, half=3.0, top=3.0, n=12):
    """A vertical wall at ``x = x0`` from z = 0 to ``top``."""
    v, f = _floor(rng, 0.0, half=half, n=n)
    v = np.stack([np.full(len(v), x0), v[:, 1], (v[:, 0] + half) * top / (2 * half)], 1)
    return v, f


def _orbit(rng, n=24, target=(0.7, -0.4), radius=2.5):
    """Cameras on an arc of 200 degrees round ``target`` (so their own middle is not it) at heights
    1.2-1.8, looking at it: (centres, viewing directions)."""
    a = np.radians(np.linspace(0, 200, n))
    c = np.stack([target[0] + radius * np.cos(a), target[1] + radius * np.sin(a), rng.uniform(1.2, 1.8, n)], 1)
    d = np.array([target[0], target[1], 0.5]) - c
    return c, d / np.linalg.norm(d, axis=1, keepdims=True)


def _similar(rng, scale):
    q = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    q *= np.sign(np.linalg.det(q))
    return scale * q, rng.normal(0.0, 1000.0, 3)


def test_an_orbit_stands_on_its_floor_in_any_units():
    """An orbit round a point above a rough floor at z = 0.3, walls and a table top (a smaller level
    surface higher up) beside it, and large shards at another height: the origin goes on the floor
    under the orbit's target, the cameras' height is theirs above the floor, and a copy of the world
    in other units, turned and moved, gives the same placement in its units."""
    rng = np.random.default_rng(3)
    floor = _floor(rng, 0.3)
    table = _floor(rng, 1.0, half=0.4, n=6, center=(0.7, -0.4))
    v, f = _join(floor, table, _wall(rng, -3.0), _wall(rng, 3.0))
    shards = np.array([[-2.0, -2.0, 0.9], [2.0, -2.0, 0.9], [0.0, 2.0, 0.9]])   # 12 level shards of 8 m^2 at 0.9:
    shards = shards + rng.uniform(-0.5, 0.5, (12, 1, 3)) * [1, 1, 0.1]          # more area than the floor's 36
    v = np.concatenate([v, shards.reshape(-1, 3)])
    f = np.concatenate([f, len(v) - 36 + np.arange(36).reshape(12, 3)])
    c, d = _orbit(rng)
    pl = find_placement(v, f, c, d, [0, 0, 1])
    assert abs(pl.ground - 0.3) < 0.02
    np.testing.assert_allclose(pl.origin[:2], [0.7, -0.4], atol=1e-9)      # the cameras' lines meet there
    assert pl.origin[2] == pytest.approx(pl.ground)
    assert pl.camera_height == pytest.approx(np.median(c[:, 2]) - pl.ground)
    assert pl.cameras == 24 and pl.share > 0.5 and "meet" in pl.middle
    a, t = _similar(rng, 1000.0)                                             # millimetres, turned, moved
    pl2 = find_placement(v @ a.T + t, f, c @ a.T + t, d @ a.T / 1000.0, a[:, 2] / 1000.0)
    np.testing.assert_allclose(pl2.origin, a @ pl.origin + t, rtol=0, atol=1e-6 * 1000)
    assert pl2.camera_height == pytest.approx(1000.0 * pl.camera_height, rel=1e-9)


def test_a_walk_stands_on_its_street_under_the_cameras_middle():
    """Cameras walking down a street all look one way: their lines never meet, so the middle is the
    cameras' own; the street is the ground, the house fronts beside it are not."""
    rng = np.random.default_rng(5)
    street = _floor(rng, 0.0, half=8.0, n=40)
    v, f = _join(street, _wall(rng, -2.0, half=8.0, top=6.0, n=30), _wall(rng, 2.0, half=8.0, top=6.0, n=30))
    y = np.linspace(-6.0, 6.0, 25)
    c = np.stack([rng.normal(0.0, 0.05, 25), y, 1.6 + rng.normal(0.0, 0.02, 25)], 1)
    d = np.tile([0.0, 1.0, -0.1], (25, 1)) + rng.normal(0.0, 0.02, (25, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    pl = find_placement(v, f, c, d, [0, 0, 1])
    assert "face one way" in pl.middle
    np.testing.assert_allclose(pl.origin[:2], c.mean(0)[:2], atol=1e-12)
    assert abs(pl.ground) < 0.02 and pl.camera_height == pytest.approx(1.6, abs=0.03)
    point, words = flat_middle(c, np.tile([0.0, 0.0, -1.0], (25, 1)), [0, 0, 1])   # looking straight down
    assert "straight down" in words and np.allclose(point, c.mean(0))


def test_a_mounted_head_on_a_wall_has_no_ground():
    """Only walls and a bump on them (the fox's head on its plaque): nothing below the cameras looks
    like ground, which is said, not guessed."""
    rng = np.random.default_rng(9)
    v, f = _join(_wall(rng, 3.0, top=4.0), _wall(rng, 2.8, half=0.3, top=0.6, n=6))
    v = v + rng.normal(0.0, 0.2, v.shape)                 # rough, as a trained mesh is: some level triangles
    a = np.radians(np.linspace(120, 240, 15))                       # an arc in front of the head, looking at it
    c = np.stack([2.8 + 1.5 * np.cos(a), 1.5 * np.sin(a), rng.uniform(1.0, 2.5, 15)], 1)
    d = np.array([2.8, 0.0, 1.7]) - c
    with pytest.raises(PlacementError, match="looks like ground"):
        find_placement(v, f, c, d / np.linalg.norm(d, axis=1, keepdims=True), [0, 0, 1])
    with pytest.raises(PlacementError, match="no level surface"):
        find_placement(*_wall(rng, 3.0), c, d, [0, 0, 1])


@pytest.mark.parametrize("fmt", ["glb", "obj", "ply"])
def test_a_placed_export_reads_back_into_its_world(tmp_path, fmt):
    """A similarity (turned, moved, scaled) is what an engine reads from the file and is recorded in
    it, so reading the file back gives the world again."""
    rng = np.random.default_rng(11)
    v, f = _floor(rng, 0.3, n=6)
    from tsplus_wgpu import TriangleModel
    model = TriangleModel(v, f, np.zeros((len(v), 1, 3)), np.ones(len(v)))
    a, _ = _similar(rng, 1.0)
    frame = engine_frame(a, origin=[1.0, -2.0, 0.3], scale=0.25)
    path = export(model, tmp_path / f"m.{fmt}", rotation=frame)
    np.testing.assert_allclose(file_frame(path), frame, atol=1e-15)
    t = trimesh.load(path, force="mesh", process=False)
    np.testing.assert_allclose(t.vertices, 0.25 * (v - [1.0, -2.0, 0.3]) @ a.T, atol=1e-6)
    back, info = load_run(path)
    np.testing.assert_allclose(back.positions, v, atol=1e-5)
    np.testing.assert_allclose(info["file_up"], a[1], atol=1e-12)
    assert "taken back into the world" in info["from"]


def _gt_run(tmp_path):
    from tsplus_wgpu import TriangleModel
    from tsplus_wgpu.data import load_scene_arg
    scene = load_scene_arg("procedural:tiny")
    g = scene.gt_mesh
    model = TriangleModel(g.vertices, g.faces, np.full((len(g.vertices), 1, 3), 0.1), np.ones(len(g.vertices)))
    run = tmp_path / "run"
    run.mkdir()
    export(model, run / "mesh.ply")
    (run / "config.json").write_text(json.dumps({"extra": {"scene": "procedural:tiny", "downscale": 1}}))
    return run, scene, model


def test_the_procedural_room_in_metres_stands_on_its_floor(tmp_path, capsys):
    """The procedural room is in metres with its floor at z = 0: placed with the cameras' true
    median height, the export keeps metres (scale 1) and puts the floor at y = 0, under the
    furniture the cameras look at."""
    run, scene, model = _gt_run(tmp_path)
    h = float(np.median([c.center[2] for c in scene.cameras]))
    out = tmp_path / "placed.glb"
    assert main(["export", str(run), "--out", str(out), "--origin", "ground", "--camera-height", f"{h!r}"]) == 0
    printed = capsys.readouterr().out
    assert "placed: the ground" in printed and "origin on the ground under" in printed and "scale 1:" in printed
    placed = trimesh.load(out, force="mesh", process=False).vertices
    floor = np.abs(model.positions[:, 2]) < 1e-9
    np.testing.assert_allclose(placed[floor, 1], 0.0, atol=1e-6)              # the floor at y = 0
    np.testing.assert_allclose(np.linalg.norm(placed - placed[0], axis=1),            # metres kept
                               np.linalg.norm(model.positions - model.positions[0], axis=1), atol=1e-5)
    assert np.linalg.norm(placed[floor][:, [0, 2]].mean(0)) < 1.0                 # the room round the origin
    back, _ = load_run(out)
    np.testing.assert_allclose(back.positions, model.positions, atol=1e-5)
    assert main(["export", str(run), "--out", str(out), "--scale", "1000", "--world-frame"]) == 0   # mm, no turn
    np.testing.assert_allclose(trimesh.load(out, force="mesh", process=False).vertices, 1000 * model.positions,
                               rtol=1e-6, atol=1e-3)


@pytest.mark.parametrize("args, says", [
    (["--scale", "-2"], "--scale -2: expected a positive"),
    (["--scale", "nan"], "--scale nan: expected a positive"),
    (["--camera-height", "0"], "--camera-height 0: expected a positive"),
    (["--scale", "2", "--camera-height", "1.5"], "give one"),
])
def test_bad_lengths_are_one_line(tmp_path, capsys, args, says):
    run, _, _ = _gt_run(tmp_path)
    assert main(["export", str(run), "--out", str(tmp_path / "o.glb"), *args]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and says in err and not (tmp_path / "o.glb").exists()


def test_origin_ground_without_cameras_says_so(tmp_path, capsys):
    run, _, _ = _gt_run(tmp_path)
    (run / "config.json").unlink()
    assert main(["export", str(run), "--out", str(tmp_path / "o.glb"), "--origin", "ground"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--origin ground: needs the cameras" in err and "--scene" in err
    (run / "config.json").write_text(json.dumps({"extra": {"scene": str(tmp_path / "moved")}}))
    assert main(["export", str(run), "--out", str(tmp_path / "o.glb"), "--camera-height", "1.5"]) == 2
    err = capsys.readouterr().err                  # one line, not a warning and then the error
    assert err.count("\n") == 1 and "--camera-height: the cameras of" in err and "moved" in err
    assert not (tmp_path / "o.glb").exists()
