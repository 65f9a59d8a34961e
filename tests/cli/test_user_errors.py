"""Every user mistake or environment failure is one line (``tsplus: error: ...``, exit 2) and a
bug keeps its traceback; ``--images`` on every command that loads a scene; the loader's
warnings printed and recorded; ``tsplus view`` of an empty mesh or without a display (issue 15)."""

import errno
import json
import subprocess
import sys

import numpy as np
import pytest

from scenes import write_colmap_scene
from tsplus_wgpu.cli.main import build_parser, command_module, error_line, main
from tsplus_wgpu.errors import UserError


def one_line(err):
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("tsplus: error: ") and "Traceback" not in err, err
    return lines[0]


def write_mesh(path, faces=True):
    import trimesh
    from tsplus_wgpu.data.procedural import load_procedural
    gt = load_procedural("tiny").gt_mesh
    pos, tri = np.asarray(gt.vertices), np.asarray(gt.faces)
    mesh = trimesh.Trimesh(vertices=pos, faces=tri if faces else np.zeros((0, 3), np.int64), process=False)
    path.write_bytes(mesh.export(file_type="ply"))
    return path


# ------------------------------------------------------------------------- the parser

@pytest.mark.parametrize("argv, words", [
    (["train", "--out", "x", "--iterations", "ten"], ("train: argument --iterations", "'ten'", "tsplus train --help")),
    (["train", "procedural:tiny"], ("--out", "required")),
    (["view"], ("view:", "path")),
    (["eval", "a", "b", "--supersample", "x"], ("eval: argument --supersample",)),
])
def test_argument_errors_are_one_line(capsys, argv, words):
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    line = one_line(capsys.readouterr().err)
    assert all(w in line for w in words), line


@pytest.mark.parametrize("argv", [
    ["train", "procedural:tiny", "--out", "o", "--images", "pics"],
    ["eval", "run", "scene", "--images", "pics"],
    ["select", "run", "--masks", "m", "--images", "pics"],
    ["view", "run", "--images", "pics"],
    ["export", "run", "--images", "pics"],
    ["inspect", "scene", "--images", "pics"],
])
def test_every_command_that_loads_a_scene_takes_images(argv):
    assert build_parser().parse_args(argv).images == "pics"


def test_eval_count_of_images_is_write_images():
    args = build_parser().parse_args(["eval", "run", "scene", "--write-images", "2"])
    assert args.write_images == 2 and args.images is None


# ------------------------------------------------------------------------- exceptions -> one line

@pytest.mark.parametrize("code, words", [
    (errno.ENOSPC, ("no space left", "write elsewhere")),
    (errno.EROFS, ("read-only", "write elsewhere")),
    (errno.EACCES, ("permission denied",)),
    (errno.ENOENT, ("no such file or folder", "check the path")),
    (errno.ENOTDIR, ("is a file, not a folder",)),
    (errno.EIO, ("input/output error",)),
])
def test_environment_errors_name_the_file(code, words):
    line = error_line(OSError(code, "system text", "/runs/a/mesh.ply"))
    assert line.startswith("/runs/a/mesh.ply: ") and all(w in line for w in words) and "\n" not in line, line


def test_other_errors_of_the_environment_and_the_users_files():
    assert "--downscale" in error_line(MemoryError("Unable to allocate 7 TiB")) and "7 TiB" in error_line(
        MemoryError("Unable to allocate 7 TiB"))
    bad = None
    try:
        b"iterations = \xff".decode("utf-8")
    except UnicodeDecodeError as exc:
        bad = exc
    assert "UTF-8" in error_line(bad)
    assert error_line(FileNotFoundError("scene x: no such file or folder")) == "scene x: no such file or folder"
    assert error_line(OSError(errno.EPIPE, "Broken pipe")) is None          # no file, no known cause: a bug


def _command_raising(monkeypatch, exc):
    module = command_module("adapters")

    def run(args):
        raise exc
    monkeypatch.setattr(module, "run", run)


@pytest.mark.parametrize("exc, words", [
    (OSError(errno.ENOSPC, "No space left on device", "/out/checkpoint.npz"), ("/out/checkpoint.npz", "no space")),
    (PermissionError(errno.EACCES, "Permission denied", "/sys/x"), ("/sys/x", "permission denied")),
    (MemoryError(), ("out of memory",)),
    (UserError("--x: bad; do y"), ("--x: bad; do y",)),
])
def test_main_prints_one_line_and_exits_2(monkeypatch, capsys, exc, words):
    _command_raising(monkeypatch, exc)
    assert main(["adapters"]) == 2
    line = one_line(capsys.readouterr().err)
    assert all(w in line for w in words), line


@pytest.mark.parametrize("exc", [KeyError("positions"), TypeError("bug"), OSError(errno.EPIPE, "Broken pipe")])
def test_a_bug_keeps_its_traceback(monkeypatch, exc):
    _command_raising(monkeypatch, exc)
    with pytest.raises(type(exc)):
        main(["adapters"])


def test_tsplus_debug_shows_the_traceback_too(monkeypatch, capsys):
    _command_raising(monkeypatch, UserError("bad input"))
    monkeypatch.setenv("TSPLUS_DEBUG", "1")
    assert main(["adapters"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" in err and err.strip().endswith("tsplus: error: bad input")


def test_a_bad_sfm_variable_is_one_line_at_the_start(monkeypatch, tmp_path, capsys):
    monkeypatch.setenv("TSPLUS_SFM_THREADS", "many")
    assert main(["train", "procedural:tiny", "--out", str(tmp_path / "run")]) == 2
    assert "TSPLUS_SFM_THREADS='many'" in one_line(capsys.readouterr().err) and not (tmp_path / "run").exists()
    monkeypatch.delenv("TSPLUS_SFM_THREADS")
    monkeypatch.setenv("TSPLUS_SFM_FOCAL", "fixed")
    assert main(["train", "procedural:tiny", "--out", str(tmp_path / "run")]) == 2
    assert "TSPLUS_SFM_FOCAL='fixed'" in one_line(capsys.readouterr().err) and not (tmp_path / "run").exists()


def test_a_bad_flag_in_a_real_process_is_one_line_and_writes_nothing(tmp_path):
    out = tmp_path / "run"
    p = subprocess.run([sys.executable, "-m", "tsplus_wgpu.cli", "train", "procedural:tiny", "--out", str(out),
                        "--max-vertices", "-5"], capture_output=True, text=True, timeout=300)
    assert p.returncode == 2 and "--max-vertices" in one_line(p.stderr) and not out.exists()


# ------------------------------------------------------------------------- scenes: --images and warnings

def test_images_folder_and_warnings(tmp_path, capsys):
    from tsplus_wgpu.cli.scenes import load_cli_scene
    root = write_colmap_scene(tmp_path / "s", missing=(3,))
    scene = load_cli_scene(str(root), images="pics")
    assert len(scene.cameras) == 3 and scene.warnings
    err = capsys.readouterr().err.strip().splitlines()
    assert err and all(line.startswith("warning: ") for line in err) and any("view_03.png" in x for x in err)
    with pytest.raises(UserError, match="--images"):
        load_cli_scene("procedural:tiny", images="pics")
    with pytest.raises(Exception):                 # the default folder (images/) is not there
        load_cli_scene(str(root))


def test_eval_takes_images_and_records_the_warnings(tmp_path, capsys):
    root = write_colmap_scene(tmp_path / "s", missing=(3,))
    mesh = write_mesh(tmp_path / "m.ply")
    out = tmp_path / "eval"
    assert main(["eval", str(mesh), str(root), "--images", "pics", "--no-splat", "--write-images", "0",
                 "--supersample", "1", "--views", "all", "--out", str(out)]) == 0
    assert "warning: skipped" in capsys.readouterr().err
    metrics = json.loads((out / "metrics.json").read_text())
    assert any("view_03.png" in w for w in metrics["scene_warnings"]) and len(metrics["views"]) == 3


# ------------------------------------------------------------------------- view

def test_view_of_a_mesh_without_faces_is_one_line(tmp_path, capsys):
    mesh = write_mesh(tmp_path / "empty.ply", faces=False)
    shot = tmp_path / "shot.png"
    assert main(["view", str(mesh), "--screenshot", str(shot)]) == 2
    assert "no triangles" in one_line(capsys.readouterr().err) and not shot.exists()


def test_view_without_a_display_suggests_screenshot(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    mesh = write_mesh(tmp_path / "m.ply")
    assert main(["view", str(mesh)]) == 2
    line = one_line(capsys.readouterr().err)
    assert "display" in line and "--screenshot" in line


def test_view_when_the_window_cannot_open_suggests_screenshot(tmp_path, capsys, monkeypatch):
    from tsplus_wgpu.cli.view import load_viewer
    v = load_viewer()

    def no_window(*a, **k):
        raise v.NoDisplayError("the window could not open (ImportError: no glfw)")
    monkeypatch.setattr(v, "display_problem", lambda: None)
    monkeypatch.setattr(v, "Viewer", no_window)
    assert main(["view", str(write_mesh(tmp_path / "m.ply"))]) == 2
    line = one_line(capsys.readouterr().err)
    assert "glfw" in line and "--screenshot" in line


def test_view_screenshot_with_scene_images_prints_warnings_and_refuses_a_file_as_folder(tmp_path, capsys):
    root = write_colmap_scene(tmp_path / "s", missing=(3,))
    mesh = write_mesh(tmp_path / "m.ply")
    shot = tmp_path / "shot.png"
    assert main(["view", str(mesh), "--scene", str(root), "--images", "pics", "--camera", "0", "--screenshot",
                 str(shot)]) == 0
    assert shot.is_file() and "warning: skipped" in capsys.readouterr().err
    (tmp_path / "file").write_text("x")
    assert main(["view", str(mesh), "--screenshot", str(tmp_path / "file" / "shot.png")]) == 2
    line = one_line(capsys.readouterr().err)
    assert str(tmp_path / "file") in line
