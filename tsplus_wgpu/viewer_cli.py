"""``tsplus view``, ``tsplus bench-viewer`` and the ``--view`` option of ``tsplus train``: the
command-line side of the viewer package (``viewer/`` in the checkout, ``tsplus_wgpu.viewer``
in the wheel)."""

from __future__ import annotations

import importlib
import importlib.util
import json
import sys
import time
from pathlib import Path

import numpy as np


def load_viewer():
    """The viewer package: ``tsplus_wgpu.viewer`` when installed from a wheel, else the
    checkout's ``viewer/`` folder (an editable install) loaded under that name."""
    try:
        return importlib.import_module("tsplus_wgpu.viewer")
    except ImportError:
        pass
    folder = Path(__file__).resolve().parent.parent / "viewer"
    if not (folder / "__init__.py").is_file():
        raise ImportError("tsplus_wgpu.viewer is not installed and no viewer/ folder is next to the package; "
                          "reinstall tsplus-wgpu")
    spec = importlib.util.spec_from_file_location("tsplus_wgpu.viewer", folder / "__init__.py",
                                                  submodule_search_locations=[str(folder)])
    mod = importlib.util.module_from_spec(spec)
    sys.modules["tsplus_wgpu.viewer"] = mod
    spec.loader.exec_module(mod)
    return mod


WALK_KEYS = ("W A S D walk, mouse drag or arrow keys look, Space jump, Shift run, R back to the start, N/B walk "
             "from the next/previous scene camera")


def add_parsers(sub):
    p = sub.add_parser("view", help="view a run folder, PLY, GLB or OBJ in a window (or render screenshots "
                                    "headless)",
                       description="Open PATH (a tsplus run folder, .ply, .glb, .obj or checkpoint .npz) in a "
                                   "window: left drag orbits, right/middle drag pans, the wheel zooms, W A S D Q E "
                                   "fly, F toggles mouse look, N/B (or ]/[) snap to the next/previous scene camera, "
                                   "X wireframe, T soft splatting render vs opaque mesh, K screenshot, H HUD, "
                                   "R reset, Esc quit. With --screenshot it renders one image offscreen (no "
                                   "display needed). --walk: first-person walking instead (gravity and collision "
                                   "against the mesh): " + WALK_KEYS + ".")
    p.add_argument("path", help="run folder, .ply, .glb, .obj or checkpoint .npz")
    p.add_argument("--scene", default=None, help="scene whose cameras to use (default: the one the run "
                                                 "folder records)")
    p.add_argument("--camera", type=int, default=None, help="start at (or render from) scene camera N")
    p.add_argument("--screenshot", default=None, metavar="PNG", help="render one frame offscreen to PNG and exit")
    p.add_argument("--size", default=None, metavar="WxH", help="canvas size (default: the camera's, at most "
                                                               "1280 wide; 960x720 without cameras)")
    p.add_argument("--splat", action="store_true", help="start with the soft splatting render (needs a model "
                                                        "with opacity / SH)")
    p.add_argument("--sigma", type=float, default=None, help="sigma of the splatting render (default: the run's "
                                                             "final sigma)")
    p.add_argument("--wireframe", action="store_true", help="start in wireframe")
    p.add_argument("--hud", action="store_true", help="draw the HUD into --screenshot images too")
    p.add_argument("--max-fps", type=float, default=60.0, help="window frame-rate cap (default 60)")
    p.add_argument("--walk", action="store_true",
                   help="walk through the mesh in first person, starting below the first (or --camera) view: "
                        "gravity, ground contact and collision with walls (trimesh queries, embree when embreex is "
                        "installed). Keys: " + WALK_KEYS + "; X, H, K, Esc as usual. With --screenshot: the walker's "
                        "view after standing for one second")
    p.add_argument("--adapter", default=None, help="GPU adapter to use (substring of its name)")

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


def add_train_view_args(p):
    """``--view`` and friends for ``tsplus train``."""
    p.add_argument("--view", action="store_true", help="open the live viewer window in the training process "
                                                       "(draws the trainer's own buffers)")
    p.add_argument("--view-fps", type=float, default=10.0, help="frame cap of the live viewer (default 10)")
    p.add_argument("--view-close", choices=["continue", "stop"], default="continue",
                   help="closing the window: training continues (default) or stops as Ctrl-C does")


def parse_size(text):
    try:
        w, h = (int(v) for v in str(text).lower().split("x"))
        assert w > 0 and h > 0
        return w, h
    except Exception:
        raise ValueError(f"--size: expected WxH (e.g. 800x600), got {text!r}") from None


def attach_live_viewer(trainer, args, scene=None):
    """Open the live window for ``tsplus train --view`` and hook it into ``trainer``; prints
    one line and returns None when no window can open (training goes on)."""
    if not getattr(args, "view", False):
        return None
    v = load_viewer()
    why = v.display_problem()
    if why is None:
        try:
            source = v.TrainerSource(trainer)
            viewer = v.Viewer(source, cameras=list(scene.cameras) if scene is not None else None,
                              background=trainer.config.background, max_fps=args.view_fps,
                              title="tsplus train (live)", camera_index=0 if scene is not None else None)
        except v.NoDisplayError as exc:
            why = str(exc)
    if why is not None:
        print(f"tsplus: --view: {why}; training continues without the window ({v.NO_DISPLAY_HINT})", flush=True)
        return None
    trainer.step_hooks.append(viewer.training_hook(stop_on_close=args.view_close == "stop"))
    return viewer


def _scene_cameras(scene_arg, downscale=1):
    if not scene_arg:
        return None
    from .train.cli import _load
    try:
        return list(_load(scene_arg, downscale or 1, 0).cameras)
    except Exception as exc:
        print(f"tsplus view: cannot load the scene {scene_arg} for its cameras ({exc}); free camera only",
              file=sys.stderr)
        return None


def run_view(args):
    from . import Renderer
    from .export import load_run
    from .train.schedules import SIGMA_FINAL
    v = load_viewer()
    model, info = load_run(args.path)
    cameras = _scene_cameras(args.scene or info.get("scene"), info.get("downscale", 1))
    if args.camera is not None:
        if not cameras:
            raise ValueError("--camera: no scene cameras (give --scene, or a run folder that records its scene)")
        if not 0 <= args.camera < len(cameras):
            raise ValueError(f"--camera: expected 0..{len(cameras) - 1}, got {args.camera}")
    size = parse_size(args.size) if args.size else None
    bg = info.get("background") or (0.0, 0.0, 0.0)
    renderer = Renderer(args.adapter)
    source = v.ModelSource(renderer, model, sigma=SIGMA_FINAL if args.sigma is None else args.sigma,
                           stats=_run_stats(args.path, model))
    if args.screenshot:
        if size is None and cameras and args.camera is not None:
            c = cameras[args.camera]
            size = (c.width, c.height)
        viewer = v.Viewer(source, cameras, size=size, offscreen=True, background=bg, hud=args.hud,
                          camera_index=args.camera, walk=args.walk)
        viewer.mode = "splat" if args.splat else "mesh"
        viewer.wire = args.wireframe
        if viewer.walking is not None:
            for _ in range(60):            # stand for a second: the walker settles on the ground
                viewer.walking.walker.step(1 / 60)
        img = viewer.frame()
        import imageio.v3 as iio
        out = Path(args.screenshot)
        out.parent.mkdir(parents=True, exist_ok=True)
        iio.imwrite(out, img)
        print(f"wrote {out} ({img.shape[1]}x{img.shape[0]}, {model.num_triangles} triangles, "
              f"{'splat' if args.splat else 'wireframe' if args.wireframe else 'mesh'}, {renderer.adapter_name})")
        return 0
    why = v.display_problem()
    viewer = None
    if why is None:
        try:
            viewer = v.Viewer(source, cameras, size=size, background=bg, max_fps=args.max_fps,
                              camera_index=args.camera, title=f"tsplus view {args.path}", walk=args.walk)
        except v.NoDisplayError as exc:
            why = str(exc)
    if viewer is None:
        print(f"tsplus view: {why}; {v.NO_DISPLAY_HINT}", file=sys.stderr)
        return 2
    viewer.mode = "splat" if args.splat else "mesh"
    viewer.wire = args.wireframe
    print(f"tsplus view: {model.num_vertices} vertices / {model.num_triangles} triangles ({info.get('from')}); "
          f"{len(cameras or [])} scene cameras; {renderer.adapter_name}")
    if viewer.walking is not None:
        w = viewer.walking.walker
        print(f"walking: eye height {w.eye_height:.3g}, body radius {w.radius:.3g}, up {np.round(w.up, 3).tolist()}, "
              f"ray queries through {w.collider.backend}; {WALK_KEYS}")
    viewer.run()
    return 0


def _run_stats(path, model):
    """HUD numbers of a run folder (last log line: iteration, loss; metrics.json: PSNR)."""
    p = Path(path)
    stats = {}
    if p.is_dir():
        log = p / "log.jsonl"
        if log.is_file():
            for line in log.read_text().splitlines()[::-1]:
                try:
                    rec = json.loads(line)
                except ValueError:
                    continue
                if "loss" in rec:
                    stats.update(iteration=rec.get("iteration"), loss=rec.get("loss"), psnr=rec.get("psnr"))
                    break
        m = p / "metrics.json"
        if m.is_file():
            try:
                stats["psnr"] = json.loads(m.read_text()).get("mesh_psnr", stats.get("psnr"))
            except ValueError:
                pass
    return stats


# ---------------------------------------------------------------------------- benchmark
def bench_mesh(n_triangles, seed=0):
    """A wavy height field of about ``n_triangles`` triangles with random vertex colours."""
    from . import TriangleModel
    side = max(2, int(round(np.sqrt(n_triangles / 2)))) + 1
    u, w = np.meshgrid(np.linspace(-1, 1, side), np.linspace(-1, 1, side), indexing="ij")
    z = 0.15 * np.sin(6 * u) * np.cos(5 * w)
    pos = np.stack([u.ravel(), w.ravel(), z.ravel()], 1)
    i = np.arange(side - 1)[:, None] * side + np.arange(side - 1)[None, :]
    i = i.ravel()
    tri = np.concatenate([np.stack([i, i + side, i + 1], 1), np.stack([i + 1, i + side, i + side + 1], 1)])
    col = np.random.default_rng(seed).uniform(0.1, 0.9, (len(pos), 3))
    from .reference import SH_C0
    return TriangleModel(pos, tri, ((col - 0.5) / SH_C0)[:, None, :], np.ones(len(pos)))


def _start_xvfb():
    import os
    import shutil
    import subprocess
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


def run_bench_viewer(args):
    from . import Renderer
    from .train.cli import _load
    from .train.trainer import TrainConfig, Trainer
    v = load_viewer()
    w, h = parse_size(args.size)
    xvfb = _start_xvfb() if args.xvfb and v.display_problem() else None
    try:
        renderer = Renderer(args.adapter)
        windowed = not args.offscreen and v.display_problem() is None
        kind = "glfw window" + (" (Xvfb)" if xvfb else "") if windowed else "offscreen canvas"
        print(f"adapter: {renderer.adapter_name}\nviewer canvas: {kind}, {w}x{h}")
        model = bench_mesh(args.triangles)
        source = v.ModelSource(renderer, model)
        viewer = v.Viewer(source, size=(w, h), offscreen=not windowed, max_fps=0)
        for _ in range(3):
            viewer.frame()
        fps_runs = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            for _ in range(args.frames):
                viewer.frame()
            fps_runs.append(args.frames / (time.perf_counter() - t0))
        viewer.close()

        scene = _load(args.scene, 1, 0)
        cfg = TrainConfig(iterations=100000, quick=True, seed=0, log_every=0, checkpoint_every=0, topology=False)
        trainer = Trainer(scene, cfg, renderer=renderer)
        trainer.train(until=5, progress=False)      # warm-up: pipelines
        live = v.Viewer(v.TrainerSource(trainer), cameras=scene.cameras, offscreen=not windowed,
                        background=cfg.background, max_fps=args.view_fps, camera_index=0)
        hook = live.training_hook()
        plain, viewed, frames = [], [], []
        for _ in range(args.repeats):
            for attach in (False, True):
                if attach:
                    trainer.step_hooks.append(hook)
                    n0 = len(live._frame_times)
                t0 = time.perf_counter()
                trainer.train(until=trainer.iteration + args.iterations, progress=False)
                dt = time.perf_counter() - t0
                if attach:
                    trainer.step_hooks.remove(hook)
                    frames.append((len(live._frame_times) - n0) / dt)
                (viewed if attach else plain).append(args.iterations / dt)
        live.close()
    finally:
        if xvfb is not None:
            try:   # close glfw's connection before its X server goes away
                import glfw
                glfw.terminate()
            except Exception:
                pass
            xvfb.kill()
    ips0, ips1 = float(np.median(plain)), float(np.median(viewed))
    result = dict(adapter=renderer.adapter_name, canvas=kind, size=[w, h], triangles=model.num_triangles,
                  viewer_fps_median=float(np.median(fps_runs)), viewer_fps_runs=fps_runs,
                  train_scene=args.scene, train_triangles=trainer.m, view_fps_cap=args.view_fps,
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
        Path(args.json).write_text(json.dumps(result, indent=2) + "\n")
        print(f"wrote {args.json}")
    return 0
