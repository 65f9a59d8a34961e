"""``tsplus bench-viewer``: viewer frames/s on a large mesh and training iterations/s with and
without the live viewer attached."""

from __future__ import annotations

import os
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np

from ..io.atomic import write_json
from ..types import SH_C0, TriangleModel
from .view import load_viewer, parse_size


def add_parser(sub):
    p = sub.add_parser("bench-viewer", help="benchmark the viewer: FPS at 100k triangles, training it/s with and "
                                            "without the live window",
                       description="Viewer frames/s on a 100k-triangle mesh (window when a display is available, "
                                   "else offscreen; --xvfb starts a virtual display) and training iterations/s with "
                                   "and without the live viewer attached (medians of --repeats), as a table and "
                                   "JSON.")
    p.add_argument("--triangles", type=int, default=100_000)
    p.add_argument("--size", default="800x600", metavar="WxH", help="viewer canvas size (default 800x600)")
    p.add_argument("--frames", type=int, default=60, help="frames timed per repeat (default 60)")
    p.add_argument("--scene", default="procedural:tiny", help="training scene (default procedural:tiny)")
    p.add_argument("--iterations", type=int, default=40, help="training iterations timed per repeat (default 40)")
    p.add_argument("--repeats", type=int, default=3, help="repeats; medians are reported (default 3)")
    p.add_argument("--view-fps", type=float, default=10.0, help="frame cap of the live viewer (default 10)")
    p.add_argument("--offscreen", action="store_true", help="use the offscreen canvas even with a display")
    p.add_argument("--xvfb", action="store_true", help="start Xvfb when no display is set")
    p.add_argument("--json", default=None, help="write the result as JSON here")
    p.add_argument("--adapter", default=None, help="GPU adapter to use (substring of its name)")
    return p


def bench_mesh(n_triangles, seed=0):
    """A wavy height field of about ``n_triangles`` triangles with random vertex colours."""
    side = max(2, int(round(np.sqrt(n_triangles / 2)))) + 1
    u, w = np.meshgrid(np.linspace(-1, 1, side), np.linspace(-1, 1, side), indexing="ij")
    z = 0.15 * np.sin(6 * u) * np.cos(5 * w)
    pos = np.stack([u.ravel(), w.ravel(), z.ravel()], 1)
    i = np.arange(side - 1)[:, None] * side + np.arange(side - 1)[None, :]
    i = i.ravel()
    tri = np.concatenate([np.stack([i, i + side, i + 1], 1), np.stack([i + 1, i + side, i + side + 1], 1)])
    col = np.random.default_rng(seed).uniform(0.1, 0.9, (len(pos), 3))
    return TriangleModel(pos, tri, ((col - 0.5) / SH_C0)[:, None, :], np.ones(len(pos)))


def _start_xvfb():
    if not shutil.which("Xvfb"):
        return None
    for n in range(90, 200):
        if Path(f"/tmp/.X{n}-lock").exists() or Path(f"/tmp/.X11-unix/X{n}").exists():
            continue
        proc = subprocess.Popen(["Xvfb", f":{n}", "-screen", "0", "1600x1200x24", "-nolisten", "tcp"],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        for _ in range(50):
            if Path(f"/tmp/.X11-unix/X{n}").exists():
                os.environ["DISPLAY"] = f":{n}"
                return proc
            if proc.poll() is not None:
                break
            time.sleep(0.1)
        proc.kill()
    return None


def _viewer_fps(v, renderer, model, size, windowed, frames, repeats):
    """Frames/s of a viewer drawing ``model`` flat out, per repeat (after 3 warm-up frames)."""
    viewer = v.Viewer(v.ModelSource(renderer, model), size=size, offscreen=not windowed, max_fps=0)
    for _ in range(3):
        viewer.frame()
    fps_runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(frames):
            viewer.frame()
        fps_runs.append(frames / (time.perf_counter() - t0))
    viewer.close()
    return fps_runs


def _train_rates(v, renderer, args, windowed):
    """Training it/s without and with the live viewer, and the viewer's frames/s meanwhile
    (lists over the repeats), and the trainer's triangle count."""
    from .. import TrainConfig, Trainer
    from ..data import load_scene_arg
    scene = load_scene_arg(args.scene, 1, 0)
    cfg = TrainConfig(iterations=100000, quick=True, seed=0, log_every=0, checkpoint_every=0, topology=False)
    trainer = Trainer(scene, cfg, renderer=renderer)
    trainer.train(until=5, progress=False)      # warm-up: pipelines
    live = v.Viewer(v.TrainerSource(trainer), cameras=trainer.scene.cameras, offscreen=not windowed,
                    background=cfg.background, max_fps=args.view_fps, camera_index=0, near=cfg.near)
    hook = live.training_hook()
    plain, viewed, frames = [], [], []
    for _ in range(args.repeats):
        for attach in (False, True):
            if attach:
                trainer.step_hooks.append(hook)
                n0 = live.frames_drawn
            t0 = time.perf_counter()
            trainer.train(until=trainer.iteration + args.iterations, progress=False)
            dt = time.perf_counter() - t0
            if attach:
                trainer.step_hooks.remove(hook)
                frames.append((live.frames_drawn - n0) / dt)
            (viewed if attach else plain).append(args.iterations / dt)
    live.close()
    return plain, viewed, frames, trainer.m


def _stop_xvfb(xvfb):
    try:   # close glfw's connection before its X server goes away
        import glfw
        glfw.terminate()
    except Exception:
        pass
    xvfb.kill()


def run(args):
    from .. import Renderer
    v = load_viewer()
    w, h = parse_size(args.size)
    xvfb = _start_xvfb() if args.xvfb and v.display_problem() else None
    try:
        renderer = Renderer(args.adapter)
        windowed = not args.offscreen and v.display_problem() is None
        kind = "glfw window" + (" (Xvfb)" if xvfb else "") if windowed else "offscreen canvas"
        print(f"adapter: {renderer.adapter_name}\nviewer canvas: {kind}, {w}x{h}")
        model = bench_mesh(args.triangles)
        fps_runs = _viewer_fps(v, renderer, model, (w, h), windowed, args.frames, args.repeats)
        plain, viewed, frames, train_triangles = _train_rates(v, renderer, args, windowed)
    finally:
        if xvfb is not None:
            _stop_xvfb(xvfb)
    ips0, ips1 = float(np.median(plain)), float(np.median(viewed))
    result = dict(adapter=renderer.adapter_name, canvas=kind, size=[w, h], triangles=model.num_triangles,
                  viewer_fps_median=float(np.median(fps_runs)), viewer_fps_runs=fps_runs,
                  train_scene=args.scene, train_triangles=train_triangles, view_fps_cap=args.view_fps,
                  train_its_without_viewer=ips0, train_its_with_viewer=ips1, train_runs_without=plain,
                  train_runs_with=viewed, live_viewer_fps=float(np.median(frames)),
                  slowdown_percent=100.0 * (1.0 - ips1 / ips0), targets={"viewer_fps_min": 20,
                                                                          "slowdown_percent_max": 15})
    rows = [("viewer FPS at %d triangles (median)" % model.num_triangles, f"{result['viewer_fps_median']:.1f}",
             ">= 20"),
            ("training it/s without viewer", f"{ips0:.2f}", ""),
            (f"training it/s with viewer (cap {args.view_fps:g} fps)", f"{ips1:.2f}", ""),
            ("slowdown", f"{result['slowdown_percent']:.1f}%", "<= 15%"),
            ("live viewer FPS during training", f"{result['live_viewer_fps']:.1f}", "")]
    print(f"{'measure':<48}{'value':>10}  target")
    for a, b, c in rows:
        print(f"{a:<48}{b:>10}  {c}")
    if args.json:
        write_json(args.json, result)
        print(f"wrote {args.json}")
    return 0
