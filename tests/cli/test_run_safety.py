"""`tsplus train` / `tsplus eval` and what they leave on disk when things go wrong: --resume on
other data, finished runs, unusable --out folders, disk full, signals, corrupt checkpoints, orphan
temp files, `eval RUN` without SCENE (issue 15)."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

ITERATIONS = 40
TRAIN = ["train", "procedural:tiny", "--preset", "quick", "--iterations", str(ITERATIONS), "--checkpoint-every", "10",
         "--no-progress"]


def _cli(*args, **kw):
    return subprocess.run([sys.executable, "-m", "tsplus_wgpu.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=300, **kw)


def _main(capsys, *args):
    """``tsplus ARGS`` in this process (for commands that fail before any GPU work)."""
    from types import SimpleNamespace

    from tsplus_wgpu.cli.main import main
    capsys.readouterr()
    rc = main([str(a) for a in args])
    out = capsys.readouterr()
    return SimpleNamespace(returncode=rc, stdout=out.out, stderr=out.err)


def _one_error_line(r, *words):
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("tsplus: error:"), r.stderr
    for w in words:
        assert w in lines[0], lines[0]
    return lines[0]


def _files(folder):
    return {p.name: p.read_bytes() for p in Path(folder).iterdir() if p.is_file()}


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """An uninterrupted run (the reference of the SIGTERM test)."""
    out = tmp_path_factory.mktemp("finished") / "run"
    r = _cli(*TRAIN, "--out", out)
    assert r.returncode == 0, r.stderr
    return out


def _rewrite_checkpoint(path, drop=(), meta_edit=None):
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files if k not in drop}
    if meta_edit is not None:
        meta = json.loads(bytes(arrays["meta"]).decode())
        meta_edit(meta)
        arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    with open(path, "wb") as f:
        np.savez(f, **arrays)


# ---------------------------------------------------------------------- resume and finished runs

def test_resume_refuses_other_data_and_finished_runs(finished, tmp_path, capsys):
    cfg = json.loads((finished / "config.json").read_text())
    data = cfg["extra"]["data"]
    assert cfg["extra"]["scene"] == data["scene"] == "procedural:tiny" and data["points"] > 0
    assert {"format", "downscale", "images", "views", "image_names", "image_sizes", "pixels"} <= data.keys()
    before = _files(finished)
    # a finished run is never replaced without --overwrite, with or without --resume
    for extra in ([], ["--resume"]):
        _one_error_line(_main(capsys, *TRAIN, "--out", finished, *extra), "finished run", "--overwrite")
    assert _files(finished) == before
    # an unfinished run: --resume names what differs, before loading anything
    run = tmp_path / "run"
    shutil.copytree(finished, run)
    (run / "metrics.json").unlink()
    kept = _files(run)
    _one_error_line(_main(capsys, *TRAIN, "--out", run, "--resume", "--downscale", "2"),
                    "--downscale 1 (checkpoint) vs 2")
    line = _one_error_line(_main(capsys, *(["train", "procedural:small"] + TRAIN[2:]), "--out", run, "--resume"),
                           "scene")
    assert "procedural:small" in line
    _one_error_line(_main(capsys, *TRAIN, "--out", run, "--resume", "--images", "images_2"), "--images")
    assert _files(run) == kept


def test_folder_scene_is_stored_absolute_and_changed_images_are_refused(tmp_path):
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import fuzz_data as fd
    fd.make_colmap(tmp_path / "scene", fd.procedural_views(), binary=False)
    # --points sfm: the synthetic images triangulate into no points, which `auto` would warn about
    args = ["train", "scene", "--preset", "quick", "--iterations", "3", "--no-progress", "--points", "sfm", "--out",
            "run"]
    r = _cli(*args, cwd=tmp_path)           # a relative SCENE
    assert r.returncode == 0, r.stderr
    cfg = json.loads((tmp_path / "run" / "config.json").read_text())
    assert cfg["extra"]["scene"] == cfg["extra"]["data"]["scene"] == str((tmp_path / "scene").resolve())
    assert cfg["extra"]["data"]["format"] == "colmap" and cfg["extra"]["data"]["views"] == 5
    (tmp_path / "run" / "metrics.json").unlink()
    img = next((tmp_path / "scene" / "images").iterdir())
    import imageio.v3 as iio
    fd.write_png(img, 255 - iio.imread(img))
    line = _one_error_line(_cli(*args, "--resume", cwd=tmp_path), "other data")
    assert "image content differ" in line and "scene" not in line.split("other data")[1].split(";")[0]


def test_data_fingerprint_names_changed_images():
    from tsplus_wgpu.data import load_procedural
    from tsplus_wgpu.errors import UserError
    from tsplus_wgpu.train.checkpoint import check_fingerprint, data_fingerprint, scene_id
    scene = load_procedural("tiny")
    a = data_fingerprint(scene, "procedural:tiny")
    assert data_fingerprint(scene, "procedural:tiny") == a
    scene.images[2] = scene.images[2].copy()
    scene.images[2][5:9, 5:9] = 1 - scene.images[2][5:9, 5:9]
    b = data_fingerprint(scene, "procedural:tiny")
    with pytest.raises(UserError, match="image content differ"):
        check_fingerprint("ck.npz", a, b)
    scene.image_names[0] = "other.png"
    with pytest.raises(UserError, match="image names differ"):
        check_fingerprint("ck.npz", a, data_fingerprint(scene, "procedural:tiny"))
    assert "older tsplus" in check_fingerprint("ck.npz", None, a)         # old checkpoints: a warning
    assert scene_id("some/rel") == str(Path("some/rel").resolve()) and scene_id("procedural") == "procedural:small"


def test_old_checkpoint_resumes_with_a_warning_and_orphans_are_removed(finished, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(finished, run)
    _rewrite_checkpoint(run / "checkpoint.npz", meta_edit=lambda m: m["config"]["extra"].pop("data"))
    orphans = [".checkpoint.npz.tmp999999999-1-0", ".test_000.tmp999999999-2-3.png"]
    for name in orphans:
        (run / name).write_bytes(b"half")
    mine = run / f".mesh.ply.tmp{os.getpid()}-1-0"          # a live process's temp file stays
    mine.write_bytes(b"x")
    r = _cli(*TRAIN, "--out", run, "--resume", "--overwrite")
    assert r.returncode == 0, r.stderr
    assert "warning:" in r.stderr and "older tsplus" in r.stderr
    assert (run / "mesh.ply").read_bytes() == (finished / "mesh.ply").read_bytes()     # re-exported, same bytes
    assert not any((run / n).exists() for n in orphans) and mine.exists()


# ---------------------------------------------------------------------- --out and the plan

def test_unusable_out_is_one_line_before_any_work(tmp_path, capsys):
    (tmp_path / "file").write_text("x")
    cases = [("", "--out"), (tmp_path / "file" / "run", "is a file"), (tmp_path / "file", "not a folder")]
    if Path("/sys").is_dir() and sys.platform.startswith("linux"):
        cases.append(("/sys/tsplus-run", "/sys"))
    for out, word in cases:
        t0 = time.perf_counter()
        _one_error_line(_main(capsys, *TRAIN, "--out", out), word)
        assert time.perf_counter() - t0 < 10
    big = tmp_path / "big"
    _one_error_line(_main(capsys, *TRAIN[:5], "10" + "0" * 12, "--out", big), "--iterations")
    assert not big.exists()


def _mount_tmpfs(where, options):
    where.mkdir()
    if not sys.platform.startswith("linux") or shutil.which("mount") is None:
        pytest.skip("needs Linux mount")
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(where)], capture_output=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({r.stderr.decode().strip()})")


def _umount(where):
    subprocess.run(["umount", str(where)], capture_output=True)


def test_read_only_out(tmp_path, capsys):
    ro = tmp_path / "ro"
    _mount_tmpfs(ro, "ro,size=64k")
    try:
        _one_error_line(_main(capsys, *TRAIN, "--out", ro / "run"), "read-only")
    finally:
        _umount(ro)


def test_disk_full_keeps_the_mesh_and_leaves_nothing_partial(finished, tmp_path):
    # room for what the same run wrote besides its checkpoint, and half the checkpoint: sizes measured on
    # the finished run, not assumed (the mesh differs from adapter to adapter: 89 kB on llvmpipe, more on a GPU)
    def pages(n):
        return -(-n // 4096) * 4096
    files = {p.name: p.stat().st_size for p in finished.iterdir()}
    size = sum(pages(n) for name, n in files.items() if name != "checkpoint.npz") + pages(files["checkpoint.npz"] // 2)
    full = tmp_path / "full"
    _mount_tmpfs(full, f"size={size}")
    try:
        r = _cli(*TRAIN[:6], "--checkpoint-every", "0", "--no-progress", "--out", full / "run")
        _one_error_line(r, "cannot write", "checkpoint.npz", "disk full")
        names = sorted(p.name for p in (full / "run").iterdir())
        assert "mesh.ply" in names and "checkpoint.npz" not in names and not [n for n in names if ".tmp" in n]
        # eval into a full disk (5 kB left): one line, no 0-byte or partial file
        shutil.rmtree(full / "run")
        (full / "fill").write_bytes(b"\0" * (size - 5 * 1024))
        r = _cli("eval", finished, "--supersample", "1", "--no-splat", "--out", full / "ev")
        _one_error_line(r, "cannot write", "disk full")
        assert not [p for p in (full / "ev").iterdir()] if (full / "ev").exists() else True
    finally:
        _umount(full)


# ---------------------------------------------------------------------- signals

def test_sigterm_checkpoints_and_resume_is_bit_identical(finished, tmp_path):
    out = tmp_path / "run"
    p = subprocess.Popen([sys.executable, "-m", "tsplus_wgpu.cli", *TRAIN, "--out", str(out)],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    while not (out / "log.jsonl").exists() and p.poll() is None and time.time() < deadline:
        time.sleep(0.02)             # the first log line: iteration 1 is done
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=120)
    if p.returncode == 0:            # pragma: no cover - a GPU fast enough to finish first
        pytest.skip("the run finished before SIGTERM arrived")
    assert p.returncode == 128 + signal.SIGTERM, err
    assert len(err.strip().splitlines()) == 1 and "SIGTERM at iteration" in err and "--resume" in err
    from tsplus_wgpu.train.checkpoint import read_checkpoint
    _, meta = read_checkpoint(out / "checkpoint.npz")
    assert 1 <= meta["iteration"] < ITERATIONS and not (out / "mesh.ply").exists()
    r = _cli(*TRAIN, "--out", out, "--resume")
    assert r.returncode == 0, r.stderr
    assert (out / "mesh.ply").read_bytes() == (finished / "mesh.ply").read_bytes()


def test_sighup_stops_training_like_ctrl_c_unless_ignored(renderer, tmp_path):
    from tsplus_wgpu.data import load_procedural
    from tsplus_wgpu.train.checkpoint import read_checkpoint
    from tsplus_wgpu.train.loop import Interrupted
    from tsplus_wgpu.train.trainer import TrainConfig, Trainer
    scene = load_procedural("tiny")
    hup = lambda tr, stats: tr.iteration != 3 or os.kill(os.getpid(), signal.SIGHUP)   # noqa: E731
    old = signal.signal(signal.SIGHUP, signal.SIG_DFL)
    try:
        t = Trainer(scene, TrainConfig(iterations=20, quick=True, log_every=0), renderer=renderer)
        t.step_hooks.append(hup)
        with pytest.raises(Interrupted) as info:
            t.train(out_dir=tmp_path, progress=False)
        assert info.value.signum == signal.SIGHUP and t.iteration == 3
        assert signal.getsignal(signal.SIGHUP) == signal.SIG_DFL
        assert read_checkpoint(tmp_path / "checkpoint.npz")[1]["iteration"] == 3
        signal.signal(signal.SIGHUP, signal.SIG_IGN)         # under nohup: SIGHUP stays ignored
        t = Trainer(scene, TrainConfig(iterations=5, quick=True, log_every=0), renderer=renderer)
        t.step_hooks.append(hup)
        assert t.train(progress=False).iteration == 5
    finally:
        signal.signal(signal.SIGHUP, old)


# ---------------------------------------------------------------------- corrupt checkpoints

def test_corrupt_checkpoint_names_the_file_and_the_array(finished, tmp_path, capsys):
    from tsplus_wgpu.train.checkpoint import CheckpointError, read_checkpoint
    src = finished / "checkpoint.npz"
    cases = []
    for name, drop in (("missing", ("logits",)), ("moment", ("exp_avg_sq_sh",))):
        path = tmp_path / f"{name}.npz"
        shutil.copy(src, path)
        _rewrite_checkpoint(path, drop=drop)
        cases.append((path, drop[0]))
    nan = tmp_path / "nan.npz"
    with np.load(src) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["positions"] = arrays["positions"].copy()
    arrays["positions"][0, 0] = np.nan
    np.savez(nan, **arrays)
    cases.append((nan, "positions"))
    flipped = tmp_path / "flipped.npz"            # bytes changed inside the stored (uncompressed) logits
    data = bytearray(src.read_bytes())
    at = data.find(b"logits.npy") + 200
    data[at:at + 64] = bytes(64)
    flipped.write_bytes(bytes(data))
    cases.append((flipped, "logits"))
    for path, array in cases:
        with pytest.raises(CheckpointError) as info:
            read_checkpoint(path)
        assert str(path) in str(info.value) and f"'{array}'" in str(info.value), str(info.value)
    run = tmp_path / "run"
    run.mkdir()
    shutil.copy(cases[0][0], run / "checkpoint.npz")
    _one_error_line(_main(capsys, *TRAIN, "--out", run, "--resume"), "checkpoint.npz", "'logits'")


# ---------------------------------------------------------------------- eval RUN

def test_eval_run_takes_its_own_scene(finished, tmp_path, capsys):
    r = _cli("eval", finished, "--supersample", "1", "--no-splat", "--out", tmp_path / "ev", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "scene of the run: procedural:tiny" in r.stdout
    assert json.loads((tmp_path / "ev" / "metrics.json").read_text())["scene"] == "procedural:tiny"
    run = tmp_path / "moved"
    shutil.copytree(finished, run)
    cfg = json.loads((run / "config.json").read_text())
    cfg["extra"]["scene"] = str(tmp_path / "gone")
    (run / "config.json").write_text(json.dumps(cfg))
    _one_error_line(_main(capsys, "eval", run, "--no-splat"), "gone", "give SCENE")


def test_a_signal_while_exporting_keeps_the_training(finished, tmp_path, monkeypatch, capsys):
    """SIGTERM during the end of training (the colour fit, the export: minutes on a large scene)
    saves the checkpoint first: `--resume` then exports the same mesh as an uninterrupted run.
    Before, the training of the whole run was lost (the loop writes no checkpoint at its end)."""
    from tsplus_wgpu.cli import train as cli_train
    from tsplus_wgpu.data.sfm import Stopped

    def stopped(*a, **k):
        raise Stopped(signal.SIGTERM)
    monkeypatch.setattr(cli_train, "_finish", stopped)
    out = tmp_path / "run"
    r = _main(capsys, *TRAIN, "--checkpoint-every", "0", "--out", out)
    assert r.returncode == 128 + signal.SIGTERM, r.stderr
    assert r.stderr.strip() == (f"tsplus: SIGTERM while exporting the mesh at iteration {ITERATIONS}; checkpoint saved "
                                f"to {out / 'checkpoint.npz'}; `--resume` exports it")
    assert not (out / "mesh.ply").exists() and not (out / "metrics.json").exists()
    r = _cli(*TRAIN, "--out", out, "--resume")
    assert r.returncode == 0, r.stderr
    assert (out / "mesh.ply").read_bytes() == (finished / "mesh.ply").read_bytes()
