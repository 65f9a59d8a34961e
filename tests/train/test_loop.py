"""The training loop: device-resident forward/backward, Trainer (quality, resume, determinism)
and ``tsplus train``."""

import numpy as np
import pytest
from scenes import random_scene

from tsplus_wgpu import DeviceModel


def test_device_model_forward_backward_equal_host_path(renderer):
    model, cam = random_scene(3, 48, 40, sh_k=4)
    dm = DeviceModel.from_model(renderer, model)
    ref = renderer.forward(model, cam, 0.7)
    dev = renderer.forward(dm, cam, 0.7)
    assert dev.model is dm and dev.model_buffers is dm.buffers
    np.testing.assert_array_equal(dev.image, ref.image)
    np.testing.assert_array_equal(dev.transmittance, ref.transmittance)
    rng = np.random.default_rng(0)
    v_img = rng.normal(size=(40, 48, 3)).astype(np.float32)
    v_t = rng.normal(size=(40, 48)).astype(np.float32)
    g_ref = renderer.backward(ref, v_img, v_t)
    # v_image as a device buffer in the kernel's layout, gradients into caller-owned buffers
    c = renderer.ctx
    v_out = c.upload(np.concatenate([v_img.reshape(-1, 3), v_t.reshape(-1, 1)], axis=1).astype(np.float32))
    n, k = model.num_vertices, model.sh_size
    out = dict(v_positions=c.buffer(12 * n), v_sh=c.buffer(12 * n * k), v_opacity=c.buffer(4 * n))
    assert renderer.backward(dev, v_out, read=False, out=out) is not None
    np.testing.assert_array_equal(c.read(out["v_positions"], np.float32, 3 * n).reshape(n, 3), g_ref.v_positions)
    np.testing.assert_array_equal(c.read(out["v_sh"], np.float32, 3 * n * k).reshape(n, k, 3), g_ref.v_sh)
    np.testing.assert_array_equal(c.read(out["v_opacity"], np.float32, n), g_ref.v_opacity)
    back = dm.to_model()
    np.testing.assert_array_equal(back.triangles, model.triangles)
    np.testing.assert_array_equal(back.positions, model.positions.astype(np.float32))


def test_device_model_errors(renderer):
    model, cam = random_scene(4, 32, 32)
    dm = DeviceModel.from_model(renderer, model)
    with pytest.raises(ValueError, match="v_transmittance"):
        renderer.backward(renderer.forward(dm, cam, 0.5), renderer.ctx.buffer(16 * 32 * 32), np.zeros((32, 32)))
    with pytest.raises(ValueError, match="needs"):
        renderer.backward(renderer.forward(dm, cam, 0.5), renderer.ctx.buffer(16 * 10))
    with pytest.raises(ValueError, match="missing"):
        DeviceModel(renderer.ctx, {"positions": dm.buffers["positions"]}, 1, 1, 1)
    with pytest.raises(ValueError, match="TriangleModel or DeviceModel"):
        renderer.forward("nope", cam, 0.5)


# ---------------------------------------------------------------------- Trainer

import json  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402

from tsplus_wgpu.train.trainer import TrainConfig, Trainer  # noqa: E402

#: Measured on lavapipe: 200 steps of the paper's schedule (30k-iteration constants) raise the
#: held-out PSNR of the tiny scene from 20.91 dB (initialisation) to about 23 dB.
QUALITY_STEPS = 200
QUALITY_GAIN_DB = 1.5


@pytest.fixture(scope="module")
def tiny():
    from tsplus_wgpu.data import load_procedural
    return load_procedural("tiny")


def test_training_raises_held_out_psnr(renderer, tiny):
    t = Trainer(tiny, TrainConfig(iterations=30000), renderer=renderer)
    before = t.evaluate()[0]
    t.train(progress=False, until=QUALITY_STEPS, log_every=0)
    after = t.evaluate()[0]
    print(f"held-out PSNR {before:.2f} -> {after:.2f} dB after {QUALITY_STEPS} steps")
    assert after > before + QUALITY_GAIN_DB
    assert np.all(np.isfinite(t.state_arrays()["positions"]))


def _arrays_equal(a, b):
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


def test_resume_is_bit_identical_and_runs_are_deterministic(renderer, tiny, tmp_path):
    cfg = TrainConfig(iterations=24, quick=True, seed=3, log_every=5)
    full = Trainer(tiny, cfg, renderer=renderer).train(out_dir=tmp_path / "a", progress=False)
    again = Trainer(tiny, cfg, renderer=renderer).train(progress=False)
    _arrays_equal(full.state_arrays(), again.state_arrays())
    part = Trainer(tiny, cfg, renderer=renderer).train(out_dir=tmp_path / "b", progress=False, until=11)
    assert part.iteration == 11
    resumed = Trainer.resume(tmp_path / "b" / "checkpoint.npz", tiny, renderer=renderer)
    assert resumed.iteration == 11
    resumed.train(progress=False)
    _arrays_equal(full.state_arrays(), resumed.state_arrays())
    # the quick schedule ends with the opacity floor at 0.9999: the model is opaque
    assert full.current_model().opacity.min() >= 0.9998
    lines = [json.loads(line) for line in (tmp_path / "a" / "log.jsonl").read_text().splitlines()]
    log = [r for r in lines if "event" not in r]
    assert [r["iteration"] for r in log] == [1, 5, 10, 15, 20, 24]
    assert any(r.get("event") == "topology" for r in lines)   # prune / densify ran and were logged
    assert {"loss", "psnr", "vertices", "triangles", "sigma", "floor", "iterations_per_s", "elapsed"} <= log[0].keys()
    other = Trainer(tiny, TrainConfig(iterations=24, quick=True, seed=4), renderer=renderer)
    assert [other.view_of(i) for i in range(1, 15)] != [full.view_of(i) for i in range(1, 15)]
    with pytest.raises(ValueError, match="seed"):
        Trainer.resume(tmp_path / "b" / "checkpoint.npz", tiny, TrainConfig(iterations=24, quick=True, seed=5),
                       renderer=renderer)


def test_view_order_is_a_permutation_per_epoch(renderer, tiny):
    t = Trainer(tiny, TrainConfig(iterations=100, seed=1), renderer=renderer)
    v = len(t.train_views)
    for e in range(3):
        assert sorted(t.view_of(e * v + i) for i in range(1, v + 1)) == sorted(t.train_views)


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "tsplus_wgpu.cli", *map(str, args)], capture_output=True,
                          text=True, timeout=300)


def test_cli_train_end_to_end(tmp_path):
    import trimesh
    out = tmp_path / "run"
    r = _cli("train", "procedural:tiny", "--out", out, "--preset", "quick", "--iterations", 16, "--no-progress")
    assert r.returncode == 0, r.stderr
    assert "held-out PSNR" in r.stdout
    for name in ("mesh.ply", "metrics.json", "log.jsonl", "config.json", "checkpoint.npz", "test_000.png"):
        assert (out / name).is_file(), name
    assert not list(out.glob(".*tmp*"))
    mesh = trimesh.load(out / "mesh.ply", process=False)
    metrics = json.loads((out / "metrics.json").read_text())
    assert len(mesh.faces) == metrics["mesh_triangles"] > 0
    assert mesh.visual.vertex_colors.shape == (len(mesh.vertices), 4)
    assert metrics["mesh_psnr"] > 10 and metrics["iterations"] == 16
    np.testing.assert_allclose(metrics["upright"]["up"], [0, 0, 1], atol=1e-6)   # the procedural world: z up
    assert metrics["upright"]["cameras"] == 8
    f = metrics["facing"]                                   # the winding turned to the views that draw it
    assert f["triangles"] == metrics["mesh_triangles"] and f["front_after"] > 0.95 and f["front_after"] >= f["front_before"]
    # resuming a finished run needs --overwrite; then it is a no-op that re-exports
    r = _cli("train", "procedural:tiny", "--out", out, "--preset", "quick", "--iterations", 16, "--no-progress",
             "--resume")
    assert r.returncode == 2 and "--overwrite" in r.stderr
    r = _cli("train", "procedural:tiny", "--out", out, "--preset", "quick", "--iterations", 16, "--no-progress",
             "--resume", "--overwrite")
    assert r.returncode == 0, r.stderr
    assert "from iteration 16 to 16" in r.stdout


@pytest.mark.parametrize("args,msg", [
    (["train", "/nonexistent/scene", "--out", "{tmp}/x"], "no such file"),
    (["train", "procedural:tiny", "--out", "{tmp}/x", "--iterations", "0"], "--iterations"),
    (["train", "procedural:tiny", "--out", "{tmp}/x", "--resume"], "no checkpoint"),
    (["train", "procedural:tiny", "--out", "{tmp}/x", "--downscale", "2"], "--downscale"),
    (["train", "procedural:huge", "--out", "{tmp}/x"], "procedural size"),
    (["train", "procedural:tiny", "--out", "{tmp}/x", "--config", "/nonexistent.json"], "--config"),
])
def test_cli_train_errors_are_one_line(tmp_path, args, msg):
    r = _cli(*[a.replace("{tmp}", str(tmp_path)) for a in args])
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("tsplus: error:") and msg in lines[0], r.stderr


def test_cli_train_refuses_to_overwrite_a_checkpoint(tmp_path):
    (tmp_path / "checkpoint.npz").write_bytes(b"x")
    r = _cli("train", "procedural:tiny", "--out", tmp_path, "--iterations", "2")
    assert r.returncode == 2 and "--resume" in r.stderr
    r = _cli("train", "procedural:tiny", "--out", tmp_path, "--iterations", "2", "--resume")
    assert r.returncode == 2 and "not a readable tsplus checkpoint" in r.stderr


def test_cli_config_file_and_flags_override(tmp_path):
    (tmp_path / "c.toml").write_text("iterations = 6\nquick = true\nseed = 5\nmax_vertices = 1200\n")
    r = _cli("train", "procedural:tiny", "--out", tmp_path / "a", "--config", tmp_path / "c.toml", "--seed", 7,
             "--no-progress")
    assert r.returncode == 0, r.stderr
    cfg = json.loads((tmp_path / "a" / "config.json").read_text())
    assert (cfg["iterations"], cfg["quick"], cfg["seed"], cfg["max_vertices"]) == (6, True, 7, 1200)
    # the written config.json is itself a valid --config: same resolved settings
    r = _cli("train", "procedural:tiny", "--out", tmp_path / "b", "--config", tmp_path / "a" / "config.json",
             "--iterations", 2, "--no-progress")
    assert r.returncode == 0, r.stderr
    cfg2 = json.loads((tmp_path / "b" / "config.json").read_text())
    assert cfg2["iterations"] == 2 and {k: v for k, v in cfg2.items() if k not in ("iterations", "extra")} == \
        {k: v for k, v in cfg.items() if k not in ("iterations", "extra")}
    (tmp_path / "bad.json").write_text('{"iterations": 5, "learning_rate": 1}')
    r = _cli("train", "procedural:tiny", "--out", tmp_path / "c", "--config", tmp_path / "bad.json")
    assert r.returncode == 2 and "unknown key" in r.stderr and "learning_rate" in r.stderr
