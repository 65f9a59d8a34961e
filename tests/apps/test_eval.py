"""`tsplus eval`: mesh-based metrics on the procedural scene, the Poisson baseline, bad input."""

import json

import numpy as np
import pytest

from tsplus_wgpu.cli.main import main
from tsplus_wgpu.data import demo_model
from tsplus_wgpu.io.export import export


@pytest.fixture(scope="module")
def gt_mesh(tmp_path_factory):
    path = tmp_path_factory.mktemp("gt") / "gt.ply"
    export(demo_model(0), path)
    return path


def test_eval_gt_mesh(gt_mesh, tmp_path, capsys):
    out = tmp_path / "ev"
    assert main(["eval", str(gt_mesh), "procedural:tiny", "--views", "all", "--supersample", "2",
                 "--out", str(out), "--write-images", "2"]) == 0
    text = capsys.readouterr().out
    assert "connectivity:" in text and "mean" in text
    res = json.loads((out / "metrics.json").read_text())
    assert len(res["views"]) == 8 and res["supersample"] == 2
    assert res["mean_psnr"] > 20 and 0 < res["mean_ssim"] <= 1 and res["mean_coverage"] > 0.99
    # the ground-truth mesh is opaque and non-overlapping: the splatting renderer agrees with the mesh
    # renderer up to edges (no supersampling here in the splat column)
    assert abs(res["mean_splat_psnr"] - res["mean_psnr"]) < 1.0
    assert res["connectivity"]["triangles"] > 0
    import imageio.v3 as iio
    img = iio.imread(out / "view_000.png")
    assert img.shape == (48, 3 * 64, 3)
    assert sorted(p.name for p in out.glob("view_*.png")) == ["view_000.png", "view_001.png"]


def test_eval_and_export_use_the_meshs_own_colours(gt_mesh, tmp_path, capsys):
    """A PLY whose vertex colour (what an engine draws) differs from its SH DC is evaluated with
    the colour; `tsplus export` keeps it by default, `--bake dc` takes SH DC, and `--bake fit`
    fits colours to the scene's training views that draw it as well as the true ones."""
    from tsplus_wgpu.io.export import read_ply_colors
    grey = tmp_path / "grey.ply"
    model = demo_model(0)
    export(model, grey, colors=np.full((model.num_vertices, 3), 0.5))
    np.testing.assert_array_equal(read_ply_colors(grey), np.round(0.5 * 255) / 255)
    psnr = {}
    for name, mesh in (("gt", gt_mesh), ("grey", grey)):
        out = tmp_path / f"ev-{name}"
        assert main(["eval", str(mesh), "procedural:tiny", "--views", "all", "--supersample", "2", "--out", str(out),
                     "--no-splat"]) == 0
        psnr[name] = json.loads((out / "metrics.json").read_text())["mean_psnr"]
    assert psnr["grey"] < psnr["gt"] - 5
    for bake, args in (("mesh", []), ("dc", ["--bake", "dc"]), ("fit", ["--bake", "fit", "--scene", "procedural:tiny"])):
        out = tmp_path / f"{bake}.ply"
        assert main(["export", str(grey), "--out", str(out), *args]) == 0
        assert main(["eval", str(out), "procedural:tiny", "--views", "all", "--supersample", "2", "--out",
                     str(tmp_path / f"ev-{bake}"), "--no-splat"]) == 0
        psnr[bake] = json.loads((tmp_path / f"ev-{bake}" / "metrics.json").read_text())["mean_psnr"]
    capsys.readouterr()
    assert abs(psnr["mesh"] - psnr["grey"]) < 1e-6 and abs(psnr["dc"] - psnr["gt"]) < 0.05
    assert psnr["fit"] > psnr["gt"] - 0.5


def _half_quad(cam, depth=2.0):
    """Two triangles covering exactly the left half of ``cam``'s image at camera depth ``depth``."""
    us, vs = [0.0, cam.width / 2, cam.width / 2, 0.0], [0.0, 0.0, cam.height, cam.height]
    xc = np.array([[(u - cam.cx) / cam.fx * depth, (v - cam.cy) / cam.fy * depth, depth] for u, v in zip(us, vs)])
    xw = (xc - cam.t) @ cam.R          # x_world = R^T (x_cam - t)
    return xw, np.array([[0, 1, 2], [0, 2, 3]], np.int32)


def test_coverage_half_full_and_empty():
    """Coverage is the fraction of pixels drawn: ~0.5 for a quad over half the image, ~1 for the
    ground-truth mesh of the procedural scene, 0 for an empty mesh; and it is exactly where a render
    on black and one on white differ."""
    from tsplus_wgpu.apps.evaluate import evaluate_mesh, mean_coverage
    from tsplus_wgpu.data import load_procedural
    from tsplus_wgpu.render.mesh_renderer import MeshRenderer
    from tsplus_wgpu.types import SH_C0, TriangleModel
    scene = load_procedural("tiny")
    mr = MeshRenderer()
    cam = scene.cameras[0]
    pos, tri = _half_quad(cam)
    half = TriangleModel(pos, tri, np.full((4, 1, 3), (0.7 - 0.5) / SH_C0), np.ones(4))
    (row,) = evaluate_mesh(half, scene, [0], mr, supersample=2)
    assert abs(row["coverage"] - 0.5) < 0.03, row["coverage"]
    black = mr.render(half, cam, supersample=2, background=(0, 0, 0)).image
    white = mr.render(half, cam, supersample=2, background=(1, 1, 1)).image
    not_drawn = np.abs(white.astype(np.float64) - black).mean(-1)
    assert abs((1 - not_drawn.mean()) - row["coverage"]) < 1e-6
    rows = evaluate_mesh(demo_model(0), scene, range(len(scene.cameras)), mr, supersample=2)
    assert min(r["coverage"] for r in rows) > 0.99 and mean_coverage(rows) > 0.99
    empty = TriangleModel(np.zeros((0, 3)), np.zeros((0, 3), np.int32), np.zeros((0, 1, 3)), np.ones(0))
    assert evaluate_mesh(empty, scene, [0], mr, supersample=2)[0]["coverage"] == 0.0


def test_eval_poisson_baseline(tmp_path, capsys):
    out = tmp_path / "pois"
    assert main(["eval", "--baseline", "poisson", "procedural:tiny", "--out", str(out), "--supersample", "1",
                 "--poisson-depth", "6", "--no-splat"]) == 0
    res = json.loads((out / "metrics.json").read_text())
    assert res["mesh"] == "baseline:poisson" and res["connectivity"]["triangles"] > 100
    assert np.isfinite(res["mean_psnr"]) and res["mean_psnr"] > 10
    assert 0.5 < res["mean_coverage"] <= 1 and all(0 <= r["coverage"] <= 1 for r in res["views"])
    assert "coverage" in capsys.readouterr().out


def test_poisson_baseline_is_deterministic():
    """Two Poisson baselines of the same points are the same mesh (pycolmap's Poisson with several
    threads orders and places vertices differently from run to run)."""
    from tsplus_wgpu.apps.evaluate import poisson_baseline
    from tsplus_wgpu.data import load_procedural
    scene = load_procedural("tiny")
    a, b = poisson_baseline(scene, depth=6), poisson_baseline(scene, depth=6)
    assert a.num_triangles > 100
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(a.triangles, b.triangles)
    np.testing.assert_array_equal(a.sh, b.sh)
    # the lowest-density 5 % of the surface's vertices are trimmed (with their triangles)
    untrimmed = poisson_baseline(scene, depth=6, trim=0.0)
    assert 0.9 * untrimmed.num_vertices < a.num_vertices < 0.97 * untrimmed.num_vertices


def test_eval_bad_input(gt_mesh, tmp_path, capsys):
    for argv, msg in ((["eval", str(tmp_path / "nope"), "procedural:tiny"], "no such run"),
                      (["eval", str(gt_mesh)], "expected RUN_OR_MESH SCENE"),
                      (["eval", str(gt_mesh), str(tmp_path / "noscene")], "no such file")):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and msg in err, err


def test_poisson_normals_face_the_cameras_that_see_them():
    """Points of the plane z = 0 seen by two cameras above it: their normals point up (+z), even
    though the nearest camera centre is a camera below the plane that looks away from it."""
    from tsplus_wgpu.apps.evaluate import oriented_normals
    from tsplus_wgpu.types import Camera

    def down_camera(centre):              # looks along world -z
        m = np.eye(4)
        m[:3, :3] = np.diag([1.0, -1.0, -1.0])
        m[:3, 3] = -m[:3, :3] @ np.asarray(centre, np.float64)
        return Camera(64, 48, 50.0, 50.0, 32.0, 24.0, m)

    g = np.linspace(-0.4, 0.4, 9)
    pts = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    pts = np.concatenate([pts, 0.01 * np.sin(7 * pts[:, :1])], axis=1)
    cams = [down_camera((0.1, 0, 2.0)), down_camera((-0.1, 0, 2.5)), down_camera((0, 0, -0.3))]
    n = oriented_normals(pts, cams)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-9)
    assert (n[:, 2] > 0.9).all()


def test_eval_of_a_run_holds_out_what_the_run_held_out(gt_mesh, tmp_path, capsys):
    """A run that left a held-out photo out of its evaluation (its pose disagreed with its matches)
    is evaluated on the same views by `tsplus eval`, whose load of the scene need not check poses;
    on another scene, or with the run's list whole, the scene's own held-out views stand."""
    from tsplus_wgpu.data import load_scene_arg
    test = list(load_scene_arg("procedural:small").test_indices)
    assert len(test) >= 3
    run = tmp_path / "run"
    run.mkdir()
    (run / "mesh.ply").write_bytes(gt_mesh.read_bytes())
    (run / "config.json").write_text(json.dumps({"extra": {"scene": "procedural:small", "downscale": 1}}))
    said = "0008.png: a held-out photo whose pose disagrees with its matches to the training photos (...)"
    (run / "metrics.json").write_text(json.dumps({"held_out_views": test[:1] + test[2:], "scene_warnings": [said],
                                                  "held_out_are_training_views": False}))

    def evaluate(*extra):
        out = tmp_path / f"ev{len(extra)}"
        assert main(["eval", str(run), *extra, "--no-splat", "--supersample", "1", "--out", str(out)]) == 0
        return [r["view"] for r in json.loads((out / "metrics.json").read_text())["views"]], capsys.readouterr().out
    views, printed = evaluate()
    assert views == test[:1] + test[2:]
    assert f"held-out views as the run evaluated them: {len(test) - 1} of {len(test)}" in printed and said in printed
    views, _ = evaluate("procedural:tiny")                                    # another scene: its own views
    assert views == list(load_scene_arg("procedural:tiny").test_indices)
    (run / "metrics.json").write_text(json.dumps({"held_out_views": test, "held_out_are_training_views": False}))
    views, printed = evaluate()
    assert views == test and "as the run evaluated" not in printed


def test_eval_of_a_run_on_its_own_scene_takes_its_downscale(gt_mesh, tmp_path, capsys):
    """`tsplus eval RUN SCENE` with the run's own scene draws the held-out views at the size the run
    trained and evaluated them (its --downscale), as `tsplus eval RUN` does, and says so; another
    --downscale, or another scene, stands as given."""
    from scenes import write_colmap_scene
    scene = write_colmap_scene(tmp_path / "scene", views=12, images="images", size="small")
    run = tmp_path / "run"
    run.mkdir()
    (run / "mesh.ply").write_bytes(gt_mesh.read_bytes())
    (run / "config.json").write_text(json.dumps({"extra": {"scene": str(scene.resolve()), "downscale": 2}}))

    def evaluate(*extra):
        out = tmp_path / f"ev{len(list(tmp_path.iterdir()))}"
        assert main(["eval", str(run), *extra, "--no-splat", "--supersample", "1", "--out", str(out)]) == 0
        return capsys.readouterr().out
    for given in ([], [str(scene)], [str(tmp_path / "." / "scene")]):
        printed = evaluate(*given)
        assert "80x60" in printed, printed
        assert ("the run's own --downscale 2" in printed) == bool(given)
    assert "160x120" in evaluate(str(scene), "--downscale", "1")
