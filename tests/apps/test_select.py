"""Object extraction / removal from 2D masks (tsplus_wgpu/select.py, ``tsplus select``).

The triangle model is the procedural scene's ground-truth mesh drawn opaque (vertex colours,
opacity 1), not a trained run: its triangles carry the object they belong to, so recall and
precision are exact counts. The masks are the scene's own object masks, rendered by the
project's NumPy z-buffer rasteriser (tsplus_wgpu/data/procedural.py), independently of the
WGSL triangle-ID pass. Recall is over the object's triangles that own a pixel in at least one
masked view (no 2D mask can say anything about the others: the underside of the sphere, the
bottom of a box on the floor, triangles smaller than a pixel at 64x48)."""

import json

import numpy as np
import pytest
from scipy.ndimage import binary_dilation, binary_erosion

from tsplus_wgpu.cli.main import main
from tsplus_wgpu.data import demo_model
from tsplus_wgpu.data import load_procedural
from tsplus_wgpu.io.export import export, read_ply
from tsplus_wgpu.apps.select import find_masks, read_mask, select_triangles, split_model, submesh

OBJECTS = ["sphere", "box_crate", "vase", "table"]


@pytest.fixture(scope="module")
def world():
    scene = load_procedural("tiny")
    return scene, demo_model(0)


def _masks(scene, name):
    k = scene.gt_mesh.object_names.index(name)
    return [m == k for m in scene.masks]


def _scores(scene, sel, name):
    g = scene.gt_mesh
    obj = g.face_object == g.object_names.index(name)
    seen = sel.visible > 0
    hit = (sel.keep & obj).sum()
    return hit / max((obj & seen).sum(), 1), hit / max(sel.keep.sum(), 1), obj & seen


def _tri_keys(model):
    """Triangles as sets of float32 vertex positions (index-free, order-free)."""
    p = model.positions.astype(np.float32)[model.triangles]            # [M, 3, 3]
    return {tuple(sorted(map(tuple, t))) for t in p.tolist()}


@pytest.mark.parametrize("name", OBJECTS)
def test_extraction_recall_precision_and_removal(world, renderer, name):
    scene, model = world
    sel = select_triangles(model, scene.cameras, _masks(scene, name), vote=0.5, renderer=renderer)
    recall, precision, obj_seen = _scores(scene, sel, name)
    assert obj_seen.sum() >= 20
    assert recall >= 0.9 and precision >= 0.9, (recall, precision)
    assert sel.views == list(range(len(scene.cameras)))
    obj, rest = split_model(model, sel.keep)
    assert obj.num_triangles + rest.num_triangles == model.num_triangles
    # removal leaves none of the object's (visible) triangles
    gt_obj = _tri_keys(submesh(model, obj_seen))
    assert not gt_obj & _tri_keys(rest)
    assert gt_obj <= _tri_keys(obj)


def test_wrong_or_poor_masks_fail(world, renderer):
    """The measure can fail: another object's mask, a shifted mask, or the vote set wrongly."""
    scene, model = world
    r, p, _ = _scores(scene, select_triangles(model, scene.cameras, _masks(scene, "box_tall"), 0.5, renderer),
                      "sphere")
    assert r < 0.1
    shifted = [np.roll(m, 4, axis=1) for m in _masks(scene, "sphere")]
    r, p, _ = _scores(scene, select_triangles(model, scene.cameras, shifted, 0.5, renderer), "sphere")
    assert r < 0.9
    # a sloppy (dilated) mask: a low vote keeps the floor around the crate, a strict one does better
    wide = [binary_dilation(m, iterations=2) for m in _masks(scene, "box_crate")]
    _, p_low, _ = _scores(scene, select_triangles(model, scene.cameras, wide, 0.05, renderer), "box_crate")
    _, p_high, _ = _scores(scene, select_triangles(model, scene.cameras, wide, 1.0, renderer), "box_crate")
    assert p_low < 0.9 and p_high > p_low + 0.2
    # a tight (eroded) mask: requiring every view loses the triangles at the silhouette
    thin = [binary_erosion(m, iterations=1) for m in _masks(scene, "sphere")]
    r_half, _, _ = _scores(scene, select_triangles(model, scene.cameras, thin, 0.5, renderer), "sphere")
    r_all, _, _ = _scores(scene, select_triangles(model, scene.cameras, thin, 1.0, renderer), "sphere")
    assert r_all < r_half - 0.2


def test_views_without_masks_are_skipped(world, renderer):
    scene, model = world
    masks = _masks(scene, "sphere")
    masks[1] = masks[4] = None
    sel = select_triangles(model, scene.cameras, masks, 0.5, renderer)
    assert sel.views == [0, 2, 3, 5, 6, 7]
    r, p, _ = _scores(scene, sel, "sphere")
    assert r >= 0.9 and p >= 0.9
    with pytest.raises(ValueError, match="vote"):
        select_triangles(model, scene.cameras, masks, 0.0, renderer)


def test_submesh_drops_unused_vertices():
    from tsplus_wgpu import TriangleModel
    pos = np.arange(18, dtype=float).reshape(6, 3)
    tri = np.array([[0, 1, 2], [3, 4, 5], [2, 3, 4]])
    m = TriangleModel(pos, tri, np.zeros((6, 1, 3)), np.linspace(0.1, 0.6, 6))
    a, b = split_model(m, [False, True, False])
    assert a.num_vertices == 3 and a.triangles.tolist() == [[0, 1, 2]]
    np.testing.assert_array_equal(a.positions, pos[3:6])
    np.testing.assert_array_equal(a.opacity, m.opacity[3:6])
    assert b.num_vertices == 5 and b.triangles.tolist() == [[0, 1, 2], [2, 3, 4]]
    np.testing.assert_array_equal(b.positions, pos[:5])


def test_mask_files(tmp_path):
    import imageio.v3 as iio
    m = np.zeros((6, 8), np.uint8)
    m[1:3, 2:5] = 7
    iio.imwrite(tmp_path / "a.png", m)
    np.testing.assert_array_equal(read_mask(tmp_path / "a.png", 8, 6), m > 0)
    rgba = np.zeros((6, 8, 4), np.uint8)
    rgba[..., 3] = m * 30                                   # a black image whose alpha is the mask
    iio.imwrite(tmp_path / "b.png", rgba)
    np.testing.assert_array_equal(read_mask(tmp_path / "b.png", 8, 6), m > 0)
    big = np.kron(m, np.ones((2, 2), np.uint8)) * 30          # twice the view's size: block majority
    iio.imwrite(tmp_path / "c.png", big)
    np.testing.assert_array_equal(read_mask(tmp_path / "c.png", 8, 6), m > 0)
    (tmp_path / "sub").mkdir()
    iio.imwrite(tmp_path / "sub" / "view_1.jpg", np.zeros((6, 8), np.uint8))
    iio.imwrite(tmp_path / "view_2.jpg", np.zeros((6, 8), np.uint8))
    iio.imwrite(tmp_path / "view_2.png", np.zeros((6, 8), np.uint8))
    found = find_masks(tmp_path, ["images/view_1.JPG", "view_2.jpg", "view_3.png", "sub/view_1.png"])
    assert [p and p.relative_to(tmp_path).as_posix() for p in found] == \
        ["sub/view_1.jpg", "view_2.png", None, "sub/view_1.jpg"]


# ----------------------------------------------------------------------------- the command

def _tiny_run(tmp_path, model):
    """A run folder of ``model`` whose vertex colours (fitted, in a real run) are not its SH DC."""
    run = tmp_path / "run"
    run.mkdir()
    export(model, run / "mesh.ply", colors=np.random.default_rng(5).random((model.num_vertices, 3)))
    (run / "config.json").write_text(json.dumps({"extra": {"scene": "procedural:tiny", "downscale": 1}}))
    return run


def _write_masks(folder, scene, name, skip=()):
    import imageio.v3 as iio
    folder.mkdir()
    for i, (img_name, m) in enumerate(zip(scene.image_names, _masks(scene, name))):
        if i not in skip:
            iio.imwrite(folder / img_name, (m * 255).astype(np.uint8))


def test_cli_end_to_end(world, tmp_path, capsys):
    scene, model = world
    run = _tiny_run(tmp_path, model)
    _write_masks(tmp_path / "masks", scene, "vase", skip=(3,))
    assert main(["select", str(run), "--masks", str(tmp_path / "masks")]) == 0
    text = capsys.readouterr().out
    assert "views used: 7 with a mask; masks missing: 1 (view_003.png)" in text
    rep = json.loads((run / "selection.json").read_text())
    assert rep["masks_missing"] == ["view_003.png"] and len(rep["views_used"]) == 7
    obj, rest = read_ply(run / "object.ply"), read_ply(run / "scene_without_object.ply")
    for f in ("object.glb", "scene_without_object.glb"):
        assert (run / f).stat().st_size > 100
    assert not list(run.glob(".*tmp*"))
    assert obj.num_triangles == rep["kept"] and rest.num_triangles == rep["remaining"]
    assert obj.num_triangles + rest.num_triangles == model.num_triangles
    # compact: every vertex used
    for part in (obj, rest):
        assert np.array_equal(np.unique(part.triangles), np.arange(part.num_vertices))
    # the object is the vase's visible triangles (the run's PLY is float32: compare as such)
    g = scene.gt_mesh
    vase = g.face_object == g.object_names.index("vase")
    mesh = read_ply(run / "mesh.ply")
    gt = _tri_keys(submesh(mesh, vase))
    got = _tri_keys(obj)
    assert len(got & gt) >= 0.9 * len(got) and len(got & gt) >= 40
    assert len(gt & _tri_keys(rest)) <= len(gt) - len(got & gt)
    # the parts keep the run's own vertex colours (not SH DC), and the GLB is +Y up like `tsplus export`'s
    from tsplus_wgpu.apps.runs import load_run
    from tsplus_wgpu.data.upright import engine_rotation, scene_upright
    from tsplus_wgpu.io.export import file_frame, read_ply_colors
    run_col = read_ply_colors(run / "mesh.ply")
    keys = {tuple(p): c for p, c in zip(np.float32(mesh.positions).tolist(), run_col)}
    obj_col = read_ply_colors(run / "object.ply")
    assert np.array_equal(obj_col, np.array([keys[tuple(p)] for p in np.float32(obj.positions).tolist()]))
    np.testing.assert_allclose(file_frame(run / "object.glb")[:3, :3], engine_rotation(scene_upright(scene)),
                               atol=1e-12)
    back, info = load_run(run / "object.glb")
    np.testing.assert_allclose(back.positions, obj.positions, atol=1e-5)
    assert "+Y up" in text or "+Y up" in capsys.readouterr().out


def test_cli_mesh_file_with_scene_and_out(world, tmp_path, capsys):
    scene, model = world
    export(model, tmp_path / "m.ply")
    _write_masks(tmp_path / "masks", scene, "sphere")
    out = tmp_path / "sel"
    assert main(["select", str(tmp_path / "m.ply"), "--masks", str(tmp_path / "masks"), "--scene", "procedural:tiny",
                 "--out", str(out), "--vote", "0.5"]) == 0
    assert (out / "object.glb").is_file() and (out / "scene_without_object.ply").is_file()
    assert "masks missing: 0" in capsys.readouterr().out


def test_cli_errors_are_one_line(world, tmp_path, capsys):
    import imageio.v3 as iio
    scene, model = world
    run = _tiny_run(tmp_path, model)
    masks = tmp_path / "masks"

    def err(*args):
        assert main(["select", *map(str, args)]) == 2
        e = capsys.readouterr().err.strip()
        assert e.count("\n") == 0 and "Traceback" not in e
        return e

    assert "--masks" in err(run, "--masks", masks) and "no such folder" in err(run, "--masks", masks)
    masks.mkdir()
    assert "no mask matches" in err(run, "--masks", masks)
    (masks / "view_000.png").write_bytes(b"not an image")
    e = err(run, "--masks", masks)
    assert "view_000.png" in e and "cannot read" in e
    iio.imwrite(masks / "view_000.png", np.zeros((30, 50), np.uint8))
    e = err(run, "--masks", masks)
    assert "view_000.png is 50x30" in e and "64x48" in e
    iio.imwrite(masks / "view_000.png", np.zeros((48, 64), np.uint8))
    assert "no triangle is under the masks" in err(run, "--masks", masks)
    assert "--vote" in err(run, "--masks", masks, "--vote", "1.5")
    export(model, tmp_path / "m.ply")
    assert "--scene" in err(tmp_path / "m.ply", "--masks", masks)
    assert "no such run" in err(tmp_path / "nothing", "--masks", masks)
    assert not (run / "object.ply").exists()


def test_help(capsys):
    with pytest.raises(SystemExit) as e:
        main(["select", "--help"])
    assert e.value.code == 0
    text = capsys.readouterr().out
    for word in ("--masks", "--vote", "--out", "--scene", "object.ply", "scene_without_object"):
        assert word in text
