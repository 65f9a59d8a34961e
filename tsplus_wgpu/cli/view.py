"""``tsplus view`` and the ``--view`` option of ``tsplus train``: the command-line side of the
viewer package (``viewer/`` in the checkout, ``tsplus_wgpu.viewer`` in the wheel)."""

from __future__ import annotations

import importlib
import importlib.util
import json
import sys
from pathlib import Path

import numpy as np

from ..errors import UserError


def load_viewer():
    """The viewer package: ``tsplus_wgpu.viewer`` when installed from a wheel, else the
    checkout's ``viewer/`` folder (an editable install) loaded under that name."""
    try:
        return importlib.import_module("tsplus_wgpu.viewer")
    except ImportError:
        pass
    package = Path(__file__).resolve().parent.parent
    folder = next((c for c in (package / "viewer", package.parent / "viewer") if (c / "__init__.py").is_file()),
                  package / "viewer")
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


def add_parser(sub):
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
    from .scenes import add_images_arg
    add_images_arg(p, help="image folder inside the scene whose cameras are used (default: the run's, else images)")
    p.add_argument("--adapter", default=None, help="GPU adapter to use (substring of its name)")
    return p


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


def attach_live_viewer(trainer, args):
    """Open the live window for ``tsplus train --view`` and hook it into ``trainer``; prints
    one line and returns None when no window can open (training goes on). The window draws the
    trainer's own buffers, in its normalised frame: so it takes the trainer's frame cameras
    (``trainer.scene.cameras``) and near plane."""
    if not getattr(args, "view", False):
        return None
    v = load_viewer()
    why = v.display_problem()
    if why is None:
        try:
            source = v.TrainerSource(trainer)
            viewer = v.Viewer(source, cameras=list(trainer.scene.cameras), background=trainer.config.background,
                              max_fps=args.view_fps, title="tsplus train (live)", camera_index=0,
                              near=trainer.config.near)
        except v.NoDisplayError as exc:
            why = str(exc)
    if why is not None:
        print(f"tsplus: --view: {why}; training continues without the window ({v.NO_DISPLAY_HINT})", flush=True)
        return None
    trainer.step_hooks.append(viewer.training_hook(stop_on_close=args.view_close == "stop"))
    return viewer


def _scene_cameras(args, info):
    """The cameras of ``--scene`` (its errors are the user's: one line, exit 2) or of the scene
    the run records (a warning and the free camera when it cannot be loaded)."""
    from .scenes import load_cli_scene
    scene_arg = args.scene or info.get("scene")
    if not scene_arg:
        return None
    images = args.images or (None if args.scene else info.get("images"))
    downscale = info.get("downscale") or 1
    if args.scene or args.images:
        return list(load_cli_scene(scene_arg, downscale, 0, images).cameras)
    try:
        return list(load_cli_scene(scene_arg, downscale, 0, images).cameras)
    except Exception as exc:
        print(f"warning: cannot load the run's scene {scene_arg} for its cameras ({exc}); free camera only (give "
              f"--scene)", file=sys.stderr)
        return None


def run(args):
    from ..render.renderer import Renderer
    from ..apps.runs import load_run
    from ..data.frame import NEAR, WorldFrame
    from ..train.schedules import SIGMA_FINAL
    v = load_viewer()
    why = None if args.screenshot else v.display_problem()
    if why is not None:              # before any loading: a window is asked for and none can open
        raise UserError(f"view: cannot open a window: {why}; {v.NO_DISPLAY_HINT}")
    model, info = load_run(args.path)
    if model.num_triangles == 0:
        raise UserError(f"{args.path}: the mesh has no triangles; nothing to view (train longer, or check the file)")
    cameras = _scene_cameras(args, info)
    if args.camera is not None:
        if not cameras:
            raise ValueError("--camera: no scene cameras (give --scene, or a run folder that records its scene)")
        if not 0 <= args.camera < len(cameras):
            raise ValueError(f"--camera: expected 0..{len(cameras) - 1}, got {args.camera}")
    size = parse_size(args.size) if args.size else None
    # a file without cameras: glTF is +Y up by its specification, and OBJ by custom; one that
    # `tsplus export --y-up` wrote is read back into its world, and its +Y is recorded
    up = info.get("file_up") or ((0.0, 1.0, 0.0) if Path(args.path).suffix.lower() in (".glb", ".gltf", ".obj")
                                 else None)
    near = WorldFrame.for_cameras(cameras).near_world() if cameras else NEAR   # the mesh is in world units
    bg = info.get("background") or (0.0, 0.0, 0.0)
    renderer = Renderer(args.adapter)
    source = v.ModelSource(renderer, model, sigma=SIGMA_FINAL if args.sigma is None else args.sigma,
                           stats=_run_stats(args.path, model), colors=info.get("colors"))
    if args.screenshot:
        if size is None and cameras and args.camera is not None:
            c = cameras[args.camera]
            size = (c.width, c.height)
        viewer = v.Viewer(source, cameras, size=size, offscreen=True, background=bg, hud=args.hud,
                          camera_index=args.camera, walk=args.walk, near=near, up=up)
        viewer.mode = "splat" if args.splat else "mesh"
        viewer.wire = args.wireframe
        if viewer.walking is not None:
            for _ in range(60):            # stand for a second: the walker settles on the ground
                viewer.walking.walker.step(1 / 60)
        img = viewer.frame()
        from ..io.atomic import write_image
        out = Path(args.screenshot)
        out.parent.mkdir(parents=True, exist_ok=True)
        write_image(out, img)          # atomic: a failed write leaves nothing at the target
        print(f"wrote {out} ({img.shape[1]}x{img.shape[0]}, {model.num_triangles} triangles, "
              f"{'splat' if args.splat else 'wireframe' if args.wireframe else 'mesh'}, {renderer.adapter_name})")
        return 0
    try:
        viewer = v.Viewer(source, cameras, size=size, background=bg, max_fps=args.max_fps,
                          camera_index=args.camera, title=f"tsplus view {args.path}", walk=args.walk, near=near,
                          up=up)
    except v.NoDisplayError as exc:     # glfw missing, or it cannot reach the display
        raise UserError(f"view: cannot open a window: {exc}; {v.NO_DISPLAY_HINT}") from None
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
