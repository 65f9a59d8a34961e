"""Export (PLY / GLB / OBJ through trimesh), the lossless PLY reader, the glTF validator,
connectivity, and bad input (one-line error, no partial file)."""

import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scenes import f32_exact, random_scene

from tsplus_wgpu import MeshRenderer, TriangleModel
from tsplus_wgpu.cli.main import main
from tsplus_wgpu.apps.runs import load_run
from tsplus_wgpu.io.export import connectivity, dc_colors, export, read_ply, to_uint8

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def model_cam():
    model, cam = f32_exact(*random_scene(7, 64, 48, sh_k=16))
    op = np.float32(np.random.default_rng(7).uniform(0.2, 1.0, model.num_vertices)).astype(np.float64)
    return TriangleModel(model.positions, model.triangles, model.sh, op), cam


@pytest.fixture(scope="module")
def mr(ctx):
    return MeshRenderer(ctx)


def test_ply_round_trip_is_lossless(model_cam, tmp_path):
    model, _ = model_cam
    export(model, tmp_path / "m.ply")
    back = read_ply(tmp_path / "m.ply")
    for name in ("positions", "triangles", "sh", "opacity"):
        assert np.array_equal(getattr(back, name), getattr(model, name)), name
    t = trimesh.load(tmp_path / "m.ply", process=False)
    assert len(t.vertices) == model.num_vertices and len(t.faces) == model.num_triangles
    assert np.array_equal(t.visual.vertex_colors[:, :3], to_uint8(dc_colors(model)))


@pytest.mark.parametrize("fmt", ["ply", "glb", "obj"])
def test_export_load_render_equals_pre_export_render(model_cam, mr, tmp_path, fmt):
    model, cam = model_cam
    path = export(model, tmp_path / f"m.{fmt}")
    back, _ = load_run(path)
    assert back.num_vertices == model.num_vertices and back.num_triangles == model.num_triangles
    t = trimesh.load(path, force="mesh", process=False)
    assert len(t.vertices) == model.num_vertices and len(t.faces) == model.num_triangles
    # OBJ colours are uint8: the pre-export render of those colours is the reference (the PLY gives
    # the SH back, so its DC colour is exact; the GLB's linear floats come back to sRGB within 1e-7)
    col8 = dc_colors(model) if fmt in ("ply", "glb") else to_uint8(dc_colors(model)) / 255.0
    before = mr.render((model.positions, model.triangles, col8), cam).image
    after = mr.render((back.positions, back.triangles, dc_colors(back)), cam).image
    np.testing.assert_allclose(after, before, atol=1e-6)
    if fmt == "ply":   # the full model too, with its SH
        assert np.array_equal(mr.render(back, cam).image, mr.render(model, cam).image)


def test_y_up_is_a_rotation_about_x(model_cam, tmp_path):
    model, _ = model_cam
    export(model, tmp_path / "m.glb", y_up=True)
    t = trimesh.load(tmp_path / "m.glb", force="mesh", process=False)
    np.testing.assert_allclose(t.vertices, model.positions * [1, -1, -1], rtol=1e-6, atol=1e-6)


def _validator():
    node = shutil.which("node")
    if node is None:
        pytest.skip("node is not installed (ci/setup.sh installs nodejs and npm)")
    mod = ROOT / ".tools" / "node_modules" / "gltf-validator"
    if not mod.is_dir():
        pytest.skip("gltf-validator is not installed (ci/setup.sh: npm install --prefix .tools gltf-validator)")
    return node


def test_glb_passes_the_khronos_validator(model_cam, tmp_path):
    node = _validator()
    model, _ = model_cam
    for y_up in (False, True):
        path = export(model, tmp_path / f"m{int(y_up)}.glb", y_up=y_up)
        out = subprocess.run([node, str(ROOT / "tests" / "gltf_validate.js"), str(path)], capture_output=True,
                             text=True, timeout=60, env=dict(os.environ, NODE_PATH=str(ROOT / ".tools" / "node_modules")))
        assert out.returncode == 0, out.stderr
        report = json.loads(out.stdout)
        assert report["issues"]["numErrors"] == 0, report["issues"]["messages"]
        assert report["info"]["totalTriangleCount"] == model.num_triangles
        assert report["info"]["totalVertexCount"] == model.num_vertices


def test_glb_is_what_an_engine_draws_as_the_photos_show(model_cam, tmp_path):
    """One unlit, double-sided, non-metallic material (glTF's default is single-sided and metallic,
    and the trained triangles' winding is arbitrary), and COLOR_0 in linear light as 32-bit floats
    (the specification's colour space; 8-bit linear would band the darks), read back into sRGB."""
    from tsplus_wgpu.io.gltf import glb_colors, linear_to_srgb, srgb_to_linear
    model, _ = model_cam
    path = export(model, tmp_path / "m.glb")
    data = path.read_bytes()
    tree = json.loads(data[20:20 + int.from_bytes(data[12:16], "little")])
    (mat,) = tree["materials"]
    assert mat["doubleSided"] is True and "KHR_materials_unlit" in mat["extensions"]
    assert mat["pbrMetallicRoughness"]["metallicFactor"] == 0.0 and "KHR_materials_unlit" in tree["extensionsUsed"]
    prim = tree["meshes"][0]["primitives"][0]
    assert prim["material"] == 0
    acc = tree["accessors"][prim["attributes"]["COLOR_0"]]
    assert acc["componentType"] == 5126 and acc["type"] == "VEC3"
    view = tree["bufferViews"][acc["bufferView"]]                         # the bytes an engine reads
    at = 20 + int.from_bytes(data[12:16], "little") + 8 + view.get("byteOffset", 0)
    lin = np.frombuffer(data, "<f4", 3 * acc["count"], at).reshape(-1, 3).astype(np.float64)
    srgb = dc_colors(model)
    np.testing.assert_allclose(lin, srgb_to_linear(srgb), atol=1e-7)
    assert np.abs(lin - srgb).max() > 0.05                               # not the sRGB values written as they are
    np.testing.assert_allclose(glb_colors(data), srgb, atol=1e-6)        # ours: back into sRGB
    np.testing.assert_allclose(linear_to_srgb(srgb_to_linear(srgb)), srgb, atol=1e-12)
    other = tmp_path / "other.glb"                                       # another program's 8-bit COLOR_0
    rgba = np.tile(np.array([[128, 10, 255, 255]], np.uint8), (len(model.positions), 1))
    trimesh.Trimesh(model.positions, model.triangles, vertex_colors=rgba, process=False).export(other)
    got = glb_colors(other.read_bytes())
    np.testing.assert_allclose(got[0], linear_to_srgb(np.array([128, 10, 255]) / 255.0), atol=1e-9)
    assert glb_colors(b"not a glb at all") is None


def test_connectivity_report():
    tri = np.array([[0, 1, 2], [1, 2, 3], [1, 2, 4], [5, 6, 7]])   # a fan of 3 on edge (1, 2), one loose
    c = connectivity(tri, 9)
    assert c["components"] == 2 and c["non_manifold_edges"] == 1 and c["used_vertices"] == 8
    assert c["shared_vertex_share"] == 0.75
    assert c["triangles_per_vertex"] == pytest.approx(12 / 8)


def _run_cli(argv, capsys):
    rc = main(argv)
    err = capsys.readouterr().err.strip()
    return rc, err


def test_bad_input_gives_one_line_and_no_partial_file(model_cam, tmp_path, capsys):
    model, _ = model_cam
    good = export(model, tmp_path / "m.ply")
    cases = [
        ([str(tmp_path / "missing"), "--out", str(tmp_path / "o.ply")], "no such run"),
        ([str(good), "--format", "fbx", "--out", str(tmp_path / "o.fbx")], "unknown format"),
        ([str(good), "--out", str(tmp_path / "nofolder" / "o.glb")], "does not exist"),
    ]
    empty = tmp_path / "empty.ply"
    export_empty = TriangleModel(np.zeros((3, 3)), np.zeros((0, 3), int), np.zeros((3, 1, 3)), np.ones(3))
    from tsplus_wgpu.io.export import encode_ply
    empty.write_bytes(encode_ply(export_empty))
    cases.append(([str(empty), "--out", str(tmp_path / "o2.ply")], "no triangles"))
    if os.geteuid() != 0:
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o500)
        cases.append(([str(good), "--out", str(ro / "o.obj")], "permission denied"))
    before = set(os.listdir(tmp_path))
    for argv, msg in cases:
        rc, err = _run_cli(["export"] + argv, capsys)
        assert rc == 2, argv
        assert len(err.splitlines()) == 1 and msg in err, err
    assert set(os.listdir(tmp_path)) == before     # nothing written, no temp file left


def test_failed_write_leaves_no_partial_file(model_cam, tmp_path, monkeypatch):
    model, _ = model_cam
    import tsplus_wgpu.io.export as ex
    target = tmp_path / "m.glb"
    target.write_bytes(b"old")

    def boom(*a, **k):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(os, "fsync", boom)        # the atomic writer (io/atomic.py) fsyncs the temp file
    with pytest.raises(ex.ExportError, match="No space left"):
        export(model, target)
    assert target.read_bytes() == b"old" and sorted(os.listdir(tmp_path)) == ["m.glb"]


def test_y_up_stands_a_run_on_its_cameras_up(model_cam, tmp_path, capsys):
    from tsplus_wgpu.data import load_scene_arg
    from tsplus_wgpu.data.upright import Upright, engine_rotation, scene_upright
    model, _ = model_cam
    run = tmp_path / "run"
    run.mkdir()
    export(model, run / "mesh.ply")
    up = np.array([0.3, -0.2, 0.9]) / np.linalg.norm([0.3, -0.2, 0.9])
    rec = Upright(up, np.cross(up, [1.0, 0.0, 0.0]) / np.linalg.norm(np.cross(up, [1.0, 0.0, 0.0])),
                  "the cameras' horizontal image axes", 2.0, 0, 9)
    (run / "metrics.json").write_text(json.dumps({"upright": rec.as_dict()}))

    def glb(*args):
        out = tmp_path / "o.glb"
        assert main(["export", str(run), "--out", str(out), *args]) == 0
        printed = capsys.readouterr()
        glb.err = printed.err
        return trimesh.load(out, force="mesh", process=False).vertices, printed.out

    pos, printed = glb("--y-up")                                        # recorded by `tsplus train`
    a = engine_rotation(Upright.from_dict(rec.as_dict()))
    np.testing.assert_allclose(pos, model.positions @ a.T, atol=2e-6)
    np.testing.assert_allclose(a @ up, [0, 1, 0], atol=1e-6)
    assert "the cameras' up" in printed and "rms roll 2.0 deg" in printed
    pos, printed = glb("--y-up", "--up-from", "world")                  # the fixed flip of y-down worlds
    np.testing.assert_allclose(pos, model.positions * [1, -1, -1], atol=2e-6)
    pos, _ = glb("--world-frame")                                       # as the world has it
    np.testing.assert_allclose(pos, model.positions, atol=2e-6)
    pos, printed = glb()                                                # a GLB is +Y up by default: glTF's convention
    np.testing.assert_allclose(pos, model.positions @ a.T, atol=2e-6)
    assert "the cameras' up" in printed
    assert main(["export", str(run), "--out", str(tmp_path / "o.glb"), "--world-frame", "--y-up"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--world-frame" in err
    (run / "metrics.json").unlink()                                     # nothing recorded: the run's scene's cameras
    (run / "config.json").write_text(json.dumps({"extra": {"scene": "procedural:tiny", "downscale": 1}}))
    pos, printed = glb("--y-up")
    a = engine_rotation(scene_upright(load_scene_arg("procedural:tiny", 1, 0)))
    np.testing.assert_allclose(pos, model.positions @ a.T, atol=2e-6)
    (run / "config.json").unlink()                                      # no cameras at all: the flip, and why
    pos, printed = glb("--y-up")
    np.testing.assert_allclose(pos, model.positions * [1, -1, -1], atol=2e-6)
    assert "no cameras known" in printed
    pos, printed = glb()                                                # by default: the world's frame, and why
    np.testing.assert_allclose(pos, model.positions, atol=2e-6)
    assert "the scene's up is unknown" in printed
    for bad in ('{"upright": {"up": "north", "forward": [0, 0]}}', '[1, 2]', '{"upright": {"up": [0, 0, 0]}}'):
        (run / "metrics.json").write_text(bad)                          # a damaged record is not trusted
        pos, printed = glb("--y-up")
        np.testing.assert_allclose(pos, model.positions * [1, -1, -1], atol=2e-6)
    (run / "config.json").write_text(json.dumps({"extra": {"scene": str(tmp_path / "gone")}}))
    pos, printed = glb("--y-up")                                        # a scene that moved: a warning line
    np.testing.assert_allclose(pos, model.positions * [1, -1, -1], atol=2e-6)
    assert glb.err.count("\n") == 1 and "warning: the cameras of" in glb.err and "gone" in glb.err


@pytest.mark.parametrize("name", ["lund", "fox"])
def test_y_up_from_a_real_scene_reads_its_cameras_not_its_pixels(model_cam, tmp_path, capsys, monkeypatch, name):
    """A run without the record takes the up from its scene's cameras and the photos' EXIF, the
    same as from the loaded scene, without reading a pixel (before: every photo at full size,
    about 40 GB of floats for 300 photos of 12 MP)."""
    from tsplus_wgpu.data import images as image_io, load_scene
    from tsplus_wgpu.data.upright import engine_rotation, scene_upright
    data = Path(os.environ.get("TSPLUS_DATA", Path(__file__).resolve().parents[3] / "shared" / "data"))
    if not (data / name).is_dir():
        pytest.skip(f"shared data scene {data / name} not found (set TSPLUS_DATA)")
    want = engine_rotation(scene_upright(load_scene(data / name, downscale=8, points="none")))
    model, _ = model_cam
    run = tmp_path / "run"
    run.mkdir()
    export(model, run / "mesh.ply")
    (run / "config.json").write_text(json.dumps({"extra": {"scene": str(data / name), "downscale": 8}}))

    def no_pixels(path):
        raise AssertionError(f"{path}: read for --y-up")
    from tsplus_wgpu.data import scene as scene_mod
    monkeypatch.setattr(image_io, "read_image_raw", no_pixels)
    monkeypatch.setattr(scene_mod, "read_image_raw", no_pixels)
    assert main(["export", str(run), "--out", str(tmp_path / "o.glb"), "--y-up"]) == 0
    assert "the cameras' up" in capsys.readouterr().out
    pos = trimesh.load(tmp_path / "o.glb", force="mesh", process=False).vertices
    np.testing.assert_allclose(pos, model.positions @ want.T, atol=2e-6)


@pytest.mark.parametrize("fmt", ["glb", "obj", "ply"])
def test_an_upright_export_reads_back_into_its_world(model_cam, mr, tmp_path, fmt):
    """A GLB / OBJ / PLY written upright records its rotation, so `tsplus eval` / `view --scene` of it
    draw the world the photos were taken in; re-exporting it upright gives the same file frame."""
    from tsplus_wgpu.data.upright import Upright, engine_rotation
    from tsplus_wgpu.io.export import file_frame
    model, cam = model_cam
    up = np.array([0.2, -0.9, 0.3]) / np.linalg.norm([0.2, -0.9, 0.3])
    fwd = np.cross(up, [1.0, 0.0, 0.0])
    a = engine_rotation(Upright(up, fwd / np.linalg.norm(fwd), "", 0.0, 0, 1))
    path = export(model, tmp_path / f"m.{fmt}", rotation=a)
    np.testing.assert_allclose(file_frame(path)[:3, :3], a, atol=1e-15)
    assert np.array_equal(file_frame(path)[:3, 3], [0, 0, 0])
    if fmt != "glb":                                                     # a rotation's record is its nine numbers
        rec = [ln for ln in path.read_bytes()[:4096].split(b"\n") if b"tsplus_world_to_file" in ln]
        assert len(rec) == 1 and len(rec[0].split()) == 11
    t = trimesh.load(path, force="mesh", process=False)                  # what an engine reads: upright
    np.testing.assert_allclose(t.vertices, model.positions @ a.T, atol=1e-5)
    back, info = load_run(path)                                          # what we read: the world
    np.testing.assert_allclose(back.positions, model.positions, atol=1e-5)
    np.testing.assert_allclose(info["file_up"], up, atol=1e-12)
    col8 = dc_colors(model) if fmt == "ply" else to_uint8(dc_colors(model)) / 255.0
    before = mr.render((model.positions, model.triangles, col8), cam).image
    after = mr.render((back.positions, back.triangles, dc_colors(back)), cam).image
    assert np.mean(np.abs(after - before)) < 1e-3
    out = tmp_path / f"again.{fmt}"                                      # upright again: the same frame
    assert main(["export", str(path), "--out", str(out), "--y-up"]) == 0
    np.testing.assert_allclose(trimesh.load(out, force="mesh", process=False).vertices, t.vertices, atol=2e-5)
    plain = export(model, tmp_path / f"plain.{fmt}")                    # no rotation: nothing recorded
    assert file_frame(plain) is None
    np.testing.assert_allclose(load_run(plain)[0].positions, model.positions, atol=1e-5)
    assert file_frame(tmp_path / "missing.glb") is None
