"""A first `tsplus train SCENE --out DIR` on a CPU adapter: the quick preset at a downscale that keeps a
training image within 2**15 = 32,768 pixels (unless --preset / --downscale / a --config file say otherwise),
the plan printed before training, an estimate of the run's duration after the first timed steps, and
a plain --resume that continues its own run."""

import dataclasses
import json
import math
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from tsplus_wgpu.cli.main import build_parser
from tsplus_wgpu.cli import plan as planning
from tsplus_wgpu.cli.train import CPU_MAX_PIXELS, cpu_downscale, cpu_iterations, plan_lines, plan_run
from tsplus_wgpu.data.scene import downscaled_size
from tsplus_wgpu.train.config import TrainConfig
from tsplus_wgpu.train.strategy.cap import initial_points_bound


@pytest.mark.parametrize("size, factor, trained", [
    ((800, 600), 4, (200, 150)), ((1000, 750), 5, (200, 150)), ((948, 712), 5, (190, 142)),
    ((1080, 1920), 8, (135, 240)), ((960, 540), 4, (240, 135)), ((1920, 1080), 8, (240, 135)),
    ((200, 150), 1, (200, 150)), ((64, 48), 1, (64, 48)),
    ((8000, 100), 3, (2667, 33)),                                   # never a side under 32 pixels
])
def test_the_cpu_downscale_is_the_smallest_that_fits(size, factor, trained):
    assert cpu_downscale(*size) == factor and downscaled_size(*size, factor) == trained
    if factor > 1 and size != (8000, 100):
        assert math.prod(trained) <= CPU_MAX_PIXELS < math.prod(downscaled_size(*size, factor - 1))


def _args(*argv, scene="scene"):
    return build_parser().parse_args(["train", scene, "--out", "run", *argv])


def _plan(*argv, cpu=True, checkpoint=None, scene="scene"):
    p = plan_run(_args(*argv, scene=scene), cpu, lambda: [(800, 600), (640, 480)], checkpoint)
    return p.preset, p.downscale, p.preset_from, p.downscale_from


def _not_asked():
    raise AssertionError("the image sizes were read")


def test_a_cpu_adapter_plans_the_quick_preset_at_a_small_size():
    assert _plan() == ("quick", 4, "CPU adapter", "CPU adapter")           # the largest image decides
    # the iterations are left to cpu_iterations, once the scene is loaded
    p = plan_run(_args(), True, lambda: [(800, 600)])
    assert (p.iterations, p.iterations_from) == (None, "CPU adapter")
    for argv in (("--iterations", "500"), ("--preset", "quick"), ("--preset", "paper")):
        assert plan_run(_args(*argv), True, lambda: [(800, 600)]).iterations is None, argv
    assert plan_run(_args(), False, lambda: [(800, 600)]).iterations is None
    assert _plan("--iterations", "500") == ("quick", 4, "CPU adapter", "CPU adapter")   # quick scales to it
    # each flag stands on its own; an explicit --downscale 1 stays 1 (and no image is looked at)
    assert _plan("--preset", "paper") == ("paper", 4, "--preset", "CPU adapter")
    assert _plan("--downscale", "1") == ("quick", 1, "CPU adapter", "--downscale")
    assert plan_run(_args("--preset", "paper", "--downscale", "1"), True, _not_asked).downscale == 1
    # the procedural scene has fixed sizes; a GPU adapter: the paper preset at full size
    assert plan_run(_args(scene="procedural:small"), True, _not_asked).downscale_from == "default"
    assert plan_run(_args(scene="procedural:small"), False, _not_asked).downscale_from == "default"
    p = plan_run(_args(), False, lambda: [(800, 600), (1600, 900)])
    assert (p.preset, p.downscale, p.preset_from, p.downscale_from) == ("paper", 1, "default", "default")
    # the initial points: at most half the vertex cap's where the CPU plan picks the iterations, else every point
    assert plan_run(_args(), True, lambda: [(800, 600)]).init_points_share == 0.5
    assert p.init_points_share is None
    for argv in (("--iterations", "500"), ("--preset", "quick")):
        assert plan_run(_args(*argv), True, lambda: [(800, 600)]).init_points_share is None, argv


@pytest.mark.parametrize("size, factor, trained", [
    ((960, 540), 1, (960, 540)), ((1600, 1200), 1, (1600, 1200)), ((1920, 1080), 2, (960, 540)),
    ((1080, 1920), 2, (540, 960)), ((4032, 3024), 3, (1344, 1008)), ((3840, 2160), 3, (1280, 720)),
    ((8000, 100), 3, (2667, 33)),                                   # never a side under 32 pixels
])
def test_a_gpu_adapter_trains_the_papers_image_size(size, factor, trained):
    """The GPU plan: the paper preset, at full size unless the long side is over 1,600 px (the
    paper's images are 1-1.6k px); then the smallest downscale that brings it there, said in
    the plan with how to undo it. --downscale and a resumed run's own stand."""
    assert planning.gpu_downscale(*size) == factor and downscaled_size(*size, factor) == trained
    p = plan_run(_args(), False, lambda: [size, (640, 480)])
    assert (p.preset, p.downscale, p.downscale_from) == ("paper", factor, "GPU adapter" if factor > 1 else "default")
    assert plan_run(_args("--downscale", "1"), False, _not_asked).downscale == 1
    if factor > 1:
        scene = SimpleNamespace(cameras=[SimpleNamespace(width=trained[0], height=trained[1])], train_indices=[0])
        lines = plan_lines(p, TrainConfig(iterations=30000), scene)
        assert f"(--downscale {factor}, for the GPU: a long side of at most 1,600 px, the paper's)" in lines[0]
        assert lines[1] == (f"GPU adapter: --downscale {factor} ({trained[0]}x{trained[1]}), the paper's image size; "
                            "pass --downscale 1 to train at full size")


def test_a_config_file_that_sets_the_preset_or_iterations_keeps_it(tmp_path):
    for text, preset in (("quick = false\n", None), ("iterations = 900\n", None), ("seed = 3\n", "quick")):
        path = tmp_path / "c.toml"
        path.write_text(text)
        assert _plan("--config", str(path))[:2] == (preset, 4), text
    # a file that sets the initial points' share keeps it (the CPU plan's 0.5 does not replace it)
    path.write_text("init_points_share = 0.0\n")
    assert plan_run(_args("--config", str(path)), True, lambda: [(800, 600)]).init_points_share is None


def test_resume_keeps_the_runs_preset_and_downscale():
    # and its iterations: a plain --resume of the CPU's 600-iteration run is not a 3000-iteration one
    p = plan_run(_args(), True, _not_asked, dict(quick=True, iterations=600, extra=dict(downscale=4)))
    assert (p.iterations, p.iterations_from) == (600, "checkpoint")
    # ... and its initial points' share, as it recorded it (runs from before it was recorded: the default)
    assert p.init_points_share is None
    assert plan_run(_args(), True, _not_asked, dict(quick=True, iterations=600, init_points_share=0.5,
                                                    extra=dict(downscale=4))).init_points_share == 0.5
    assert plan_run(_args("--iterations", "900"), True, _not_asked, dict(quick=True, iterations=600)).iterations is None
    ckpt = dict(quick=True, extra=dict(downscale=4, scene="/x"))
    for cpu in (True, False):
        assert _plan(cpu=cpu, checkpoint=ckpt) == ("quick", 4, "checkpoint", "checkpoint")
    assert _plan(checkpoint=dict(quick=False, extra={})) == ("paper", 1, "checkpoint", "checkpoint")
    assert _plan("--downscale", "2", checkpoint=ckpt)[1:] == (2, "checkpoint", "--downscale")   # refused later


def _scene(width=200, height=150, views=1, points=0):
    cams = [SimpleNamespace(width=width, height=height) for _ in range(views)]
    return SimpleNamespace(cameras=cams, train_indices=list(range(views)), points=np.zeros((points, 3)))


def test_the_plan_lines_say_what_was_chosen_and_how_to_undo_it():
    scene = _scene()
    cfg = TrainConfig.preset(quick=True)
    cpu = plan_run(_args(), True, lambda: [(800, 600)])
    # one view, 600 quick iterations: the first prune at 80 + 10 (outdoor); before it the initial mesh's 100,000
    # triangles, after it 1.08 x the vertex cap's 60,000 (2 x 30,000 pixels), each with 30,000 pixels
    early, late = 2.2e-6 * 30_000 + 2.26e-6 * 100_000, 1.08 * (2.2e-6 * 30_000 + 2.26e-6 * 60_000)
    assert planning.cpu_seconds(dataclasses.replace(cfg, iterations=600), scene.cameras, 100_000) == \
        pytest.approx(89 * early + 511 * late, rel=1e-12)                  # 137 s
    # the shape of that model, for the early estimate (RateEstimate's later_cost): 0.75x; no prune, no shape
    assert planning.cpu_late_ratio(cfg, scene.cameras, 100_000) == pytest.approx(late / early, rel=1e-12)
    assert planning.cpu_late_ratio(dataclasses.replace(cfg, topology=False), scene.cameras, 100_000) is None
    assert plan_lines(cpu, dataclasses.replace(cfg, iterations=600), scene, triangles=100_000) == [
        "plan: quick preset (for the CPU adapter), 600 iterations (for the CPU adapter) at 200x150 (--downscale 4, "
        "for the CPU adapter)",
        "CPU adapter: quick preset, 600 iterations, --downscale 4 (200x150) so the training takes about 2 min on 2 "
        "cores; pass --preset paper --downscale 1 for the paper's run"]
    asked = plan_run(_args("--preset", "quick", "--downscale", "4"), True, _not_asked)
    assert plan_lines(asked, cfg, scene) == [
        "plan: quick preset (as given), 3,000 iterations at 200x150 (--downscale 4, as given)"]


def test_the_cpu_default_takes_the_most_iterations_that_fit_its_time():
    # the CPU adapter's plan meshes at most half the vertex cap's points (elsewhere every point)
    assert TrainConfig().init_points_share == 0.0 and planning.CPU_INIT_POINTS_SHARE == 0.5
    cfg = dataclasses.replace(TrainConfig.preset(quick=True), init_points_share=planning.CPU_INIT_POINTS_SHARE)
    meshed = lambda scene: min(len(scene.points), initial_points_bound(cfg, scene.cameras))
    seconds = lambda n, scene: planning.cpu_seconds(dataclasses.replace(cfg, iterations=n), scene.cameras,
                                                    planning.TRIANGLES_PER_POINT * meshed(scene))
    chosen = {}
    for size, points in (((200, 150), 9000), ((240, 135), 9000), ((135, 240), 17_000), ((190, 142), 1500),
                         ((64, 48), 100)):
        scene = _scene(*size, views=50, points=points)
        n = chosen[size, points] = cpu_iterations(cfg, scene)
        assert n % 100 == 0 and 600 <= n <= 3000
        assert n == 3000 or (seconds(n, scene) <= planning.CPU_TRAIN_SECONDS < seconds(n + 100, scene)), size
        assert cpu_iterations(dataclasses.replace(cfg, iterations=7), scene) == n     # the config's own: ignored
    # more points (a larger initial mesh) or more pixels: fewer iterations; a tiny scene: the quick preset's own
    assert chosen[(135, 240), 17_000] < chosen[(200, 150), 9000] < 3000 == chosen[(64, 48), 100]
    assert cpu_iterations(cfg, _scene(1000, 1000, views=50, points=100_000)) == 600          # never fewer
    # none_fit (the slow machine's hint: None, no advice) only where not even 600 fit
    assert cpu_iterations(cfg, _scene(1000, 1000, views=50, points=100_000), none_fit=None) is None
    small = _scene(200, 150, views=50, points=9000)
    assert cpu_iterations(cfg, small, seconds=seconds(600, small), none_fit=None) == 600
    assert cpu_iterations(cfg, small, seconds=seconds(600, small) * 0.99, none_fit=None) is None
    assert cpu_iterations(cfg, _scene(200, 150, views=50, points=9000), seconds=10 ** 6) == 3000
    # only the points the run meshes count: at most init_points_share (0.5) x the vertex cap (60,000) = 30,000
    most = initial_points_bound(cfg, _scene(200, 150, views=50).cameras)
    assert most == 30_000
    assert cpu_iterations(cfg, _scene(200, 150, views=50, points=150_000)) == \
        cpu_iterations(cfg, _scene(200, 150, views=50, points=most)) > \
        cpu_iterations(dataclasses.replace(cfg, init_points_share=0.0), _scene(200, 150, views=50, points=150_000))


def test_the_slower_machines_line_counts_the_iterations_as_iterations_n_trains():
    """RateEstimate's ``planned`` for a CPU plan's run: the time model's seconds of the run as
    planned (half the cap in points), and the iterations that fit the plan's time r times slower
    as ``--iterations N`` trains them, meshing every point: fewer than the plan's share would give
    where the scene has more points than that share; None where not even 600 fit."""
    cfg = dataclasses.replace(TrainConfig.preset(quick=True), init_points_share=planning.CPU_INIT_POINTS_SHARE,
                              iterations=2000)
    scene = _scene(200, 150, views=50, points=40_000)          # over the share's 30,000
    seconds, fewer = planning.slower_machine(cfg, scene, 345_000)
    assert seconds == planning.cpu_seconds(cfg, scene.cameras, 345_000)
    every = dataclasses.replace(cfg, init_points_share=0.0)
    assert fewer(1.5) == cpu_iterations(every, scene, planning.CPU_TRAIN_SECONDS / 1.5) \
        < cpu_iterations(cfg, scene, planning.CPU_TRAIN_SECONDS / 1.5)
    assert fewer(1.0) == cpu_iterations(every, scene)
    assert fewer(100.0) is None


def _cli(*args, cwd):
    return subprocess.run([sys.executable, "-m", "tsplus_wgpu.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=300, cwd=cwd)


def test_a_first_run_prints_its_plan_and_estimate_and_resumes_plainly(renderer, tmp_path):
    if not renderer.ctx.is_cpu:
        pytest.skip("the CPU adapter's defaults: this adapter is not a CPU")
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import fuzz_data as fd
    cams, imgs, names, xyz, rgb = fd.procedural_views()        # 64x48, shown at 256x192 (49,152 pixels)
    big = ([c.scaled(4) for c in cams], [np.kron(im, np.ones((4, 4, 1), np.uint8)) for im in imgs], names, xyz, rgb)
    fd.make_colmap(tmp_path / "scene", big, binary=False)
    r = _cli("train", "scene", "--out", "run", "--iterations", 30, "--no-progress", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    out = r.stdout.splitlines()
    assert "plan: quick preset (for the CPU adapter), 30 iterations at 128x96 (--downscale 2, for the CPU adapter)" \
        in out, r.stdout          # --iterations given: the CPU adapter's choice does not apply
    assert any(x.startswith("CPU adapter: quick preset, --downscale 2 (128x96) so the training takes about") for x in out)
    assert [x for x in out if x.startswith("estimate: 5 iterations left at ")] and "(measured over steps 6-25)" in r.stdout
    assert any(x.startswith("vertex cap: 24,576 (vertex budget 2.0 x 12,288 training pixels") for x in out)
    cfg = json.loads((tmp_path / "run" / "config.json").read_text())
    assert cfg["quick"] and cfg["extra"]["downscale"] == 2 and cfg["vertex_budget"] == 2.0
    assert cfg["init_points_share"] == 0.0          # its iterations given: every point
    # resuming takes the run's own preset and downscale; another --downscale is refused in one line
    r = _cli("train", "scene", "--out", "run", "--iterations", 30, "--resume", "--overwrite", "--no-progress",
             cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "plan: quick preset (the run's own), 30 iterations at 128x96 (--downscale 2, the run's own)" in r.stdout
    assert "from iteration 30 to 30" in r.stdout
    r = _cli("train", "scene", "--out", "run", "--iterations", 30, "--resume", "--overwrite", "--downscale", 1,
             cwd=tmp_path)
    assert r.returncode == 2 and "--downscale 2 (checkpoint) vs 1" in r.stderr


def test_a_default_cpu_run_trains_the_iterations_its_plan_chose(renderer, tmp_path, monkeypatch, capsys):
    """No --iterations, --preset or --config: the CPU adapter's count comes from cpu_iterations, given the
    loaded scene at its training size (patched to a short run here) and written to config.json."""
    if not renderer.ctx.is_cpu:
        pytest.skip("the CPU adapter's defaults: this adapter is not a CPU")
    from tsplus_wgpu.cli import train as train_cli
    from tsplus_wgpu.cli.main import main
    asked = []

    def short(cfg, scene, seconds=planning.CPU_TRAIN_SECONDS):
        asked.append((cfg.quick, scene.cameras[scene.train_indices[0]].width, len(scene.points), cfg.init_points_share))
        return 12
    monkeypatch.setattr(train_cli, "cpu_iterations", short)
    monkeypatch.chdir(tmp_path)
    assert main(["train", "procedural:tiny", "--out", "run", "--no-progress", "--color-detail", "off"]) == 0
    assert asked and asked[0][:2] == (True, 64) and asked[0][2] > 0
    assert "plan: quick preset (for the CPU adapter), 12 iterations (for the CPU adapter) at 64x48" in capsys.readouterr().out
    saved = json.loads((tmp_path / "run" / "config.json").read_text())
    # the plan's time model and the run itself mesh at most half the vertex cap's points
    assert saved["iterations"] == 12 and saved["init_points_share"] == 0.5 == asked[0][3]


def test_points_flag_chooses_the_initial_points(tmp_path):
    """`--points`: the scene's SfM points by default, frusta points when asked; the procedural
    scene refuses it in one line."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import fuzz_data as fd
    from tsplus_wgpu.cli.scenes import load_cli_scene
    views = fd.procedural_views()
    fd.make_colmap(tmp_path / "scene", views, binary=False)
    sfm = load_cli_scene(str(tmp_path / "scene"), warn=False)
    assert sfm.points_source == "sfm" and 0 < len(sfm.points) <= len(views[3])
    fr = load_cli_scene(str(tmp_path / "scene"), warn=False, points="frusta")
    assert fr.points_source == "frusta" and fr.points.shape != sfm.points.shape
    assert any("frusta (as asked)" in str(w) for w in fr.warnings)
    assert build_parser().parse_args(["train", "x", "--out", "o", "--points", "triangulate"]).points == "triangulate"
    r = _cli("train", "procedural:tiny", "--out", "run", "--points", "frusta", cwd=tmp_path)
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [
        "tsplus: error: --points frusta: the procedural scene has its own points; drop --points"], r.stderr
