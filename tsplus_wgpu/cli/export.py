"""``tsplus export``: write a trained run (or a mesh, or a checkpoint) as PLY / GLB / OBJ."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from ..apps.runs import load_run
from ..errors import UserError
from ..io.export import (BAKES, FORMATS, Y_UP, ExportError, bake_views, connectivity, connectivity_line, dc_colors,
                         export)
from .scenes import add_images_arg, load_cli_scene


def add_parser(sub):
    p = sub.add_parser("export", help="write a trained run (or a mesh) as PLY / GLB / OBJ",
                       description="Write RUN (a folder written by `tsplus train`, a .ply/.glb/.obj mesh or a "
                                   "checkpoint .npz) as PLY (float32 positions, uint8 RGB, full SH and opacity as "
                                   "extra vertex properties; reads back losslessly), GLB (glTF 2.0 for an engine: +Y up when "
                                   "the scene's up is known, one unlit double-sided material, linear COLOR_0) or "
                                   "OBJ (vertex colours). Written atomically; prints the connectivity report.")
    p.add_argument("run", help="run folder, mesh file or checkpoint")
    p.add_argument("--format", default=None, help="ply, glb or obj (default: --out's extension, else ply)")
    p.add_argument("--out", default=None, help="output file (default: RUN/mesh_export.FORMAT, or beside the mesh)")
    p.add_argument("--y-up", action="store_true",
                   help="stand the mesh upright for an engine: +Y is the scene's up, estimated from its cameras "
                        "(recorded by `tsplus train`, else from the run's scene or --scene), -Z the cameras' mean "
                        "viewing direction; a rotation, so lengths and the world's units are kept")
    p.add_argument("--world-frame", action="store_true",
                   help="keep the world's own frame; without it a GLB is written +Y up (glTF's convention) whenever "
                        "the scene's up is known, as with --y-up")
    p.add_argument("--up-from", choices=("cameras", "world"), default="cameras",
                   help="with --y-up: cameras (default) or world (the world's -y is up, as OpenCV's y-down worlds "
                        "have it: (x, -y, -z))")
    p.add_argument("--origin", choices=("world", "ground"), default="world",
                   help="world (default: the world's own origin) or ground: the origin on the ground under the "
                        "middle of what the photos look at (the ground: the level surface below the cameras); "
                        "implies --y-up and needs the run's scene or --scene")
    p.add_argument("--scale", type=float, default=None, metavar="F",
                   help="multiply every length by F (e.g. metres per world unit); default 1: the world's units")
    p.add_argument("--camera-height", type=float, default=None, metavar="H",
                   help="scale so that the cameras stand H above the ground (e.g. 1.5 for photos taken standing, "
                        "in metres): an estimate of metric size; implies --y-up, needs the scene's cameras")
    p.add_argument("--bake", choices=BAKES, default="mesh",
                   help="vertex colour: mesh (the mesh file's own colours: for a run, fitted to the training photos "
                        "unless it was trained with --mesh-colors dc; SH DC for a checkpoint), dc (SH DC term), fit "
                        "(least-squares fit to the training views through the depth-tested mesh) or views (photo "
                        "averaged at each vertex over the training views that see it); fit and views need the run's "
                        "scene or --scene")
    p.add_argument("--scene", default=None,
                   help="the scene whose cameras give the up, the ground and --bake's views (default: the run's)")
    add_images_arg(p, help="image folder inside the scene for --bake views (default: the run's, else images)")
    p.add_argument("--adapter", default=None, help="GPU adapter to use (substring of its name)")
    return p


def _bake(args, model, info):
    """``(colors [N, 3], description)`` for ``--bake fit`` or ``views``."""
    scene_arg = args.scene or info.get("scene")
    if not scene_arg:
        raise ExportError(f"--bake {args.bake}: the run names no scene; give --scene")
    images = args.images or (None if args.scene else info.get("images"))
    scene = load_cli_scene(scene_arg, int(info.get("downscale") or 1) if not args.scene else 1, 0, images)
    from ..render.mesh_renderer import MeshRenderer
    mr = MeshRenderer(args.adapter)
    views = list(scene.train_indices or range(len(scene.cameras)))
    t0 = time.perf_counter()
    if args.bake == "views":
        colors, seen = bake_views(model, scene, views, mesh_renderer=mr)
        print(f"baked colours from {len(views)} training views on {mr.adapter_name} in "
              f"{time.perf_counter() - t0:.1f}s ({100 * np.mean(seen > 0):.1f}% of vertices seen; the others keep SH DC)")
        return colors, "training views"
    from ..render.mesh_fit import fit_vertex_colors
    bg = info.get("background") or (0.0, 0.0, 0.0)
    colors, fit = fit_vertex_colors(model.positions, model.triangles, [scene.cameras[v] for v in views],
                                    [scene.images[v] for v in views], dc_colors(model), scene.frame().near_world(),
                                    mr, background=tuple(float(x) for x in bg))
    print(f"fitted colours to {len(views)} training views on {mr.adapter_name} in {time.perf_counter() - t0:.1f}s "
          f"({100 * fit['observed'] / max(model.num_vertices, 1):.1f}% of vertices seen; the others keep SH DC)")
    return colors, "a least-squares fit to the training views"


def _placing(args) -> str:
    """The flag that needs the scene's cameras to place the mesh, or ``""``."""
    return "--origin ground" if args.origin == "ground" else "--camera-height" if args.camera_height is not None else ""


def _scene_cameras(args, info):
    """``(cameras, photo files)`` of the run's scene or ``--scene`` (poses and EXIF, no pixel read),
    or ``(None, None)``: with a warning line where they cannot be read, or the one-line error
    when placing the mesh (:func:`_placing`) needs them."""
    scene_arg = args.scene or info.get("scene")
    if not scene_arg:
        if _placing(args):
            raise ExportError(f"{_placing(args)}: needs the cameras of the run's scene; the run names none: give "
                              "--scene")
        return None, None
    from ..data.errors import SceneError
    from ..data.loader import load_scene_arg, scene_cameras
    images = args.images or (None if args.scene else info.get("images"))
    try:
        if str(scene_arg).startswith("procedural"):
            return load_scene_arg(scene_arg).cameras, None
        return scene_cameras(scene_arg, images)
    except (SceneError, UserError, OSError) as exc:
        if _placing(args):
            raise ExportError(f"{_placing(args)}: the cameras of {scene_arg} could not be read ({exc}); give "
                              "--scene") from None
        print(f"warning: the cameras of {scene_arg} could not be read ({exc}), so the scene's up is unknown",
              file=sys.stderr)
        return None, None


def _engine_frame(args, info, cams, auto=False):
    """``(rotation or None, words)``: how ``--y-up`` turns this run's world into an engine's.
    ``cams``: a callable giving :func:`_scene_cameras`'s pair (read once, when needed). ``auto``:
    a GLB without ``--y-up`` or ``--world-frame``, turned only when the scene's up is known."""
    from ..data.upright import Upright, engine_rotation, estimate_up, files_upright
    if not args.y_up and not auto:
        return None, ""
    if args.up_from == "world" and args.y_up:
        return Y_UP, "y up: the world's -y"
    up = Upright.from_dict(info["upright"]) if isinstance(info.get("upright"), dict) else None
    if up is None:
        cameras, files = cams()
        if cameras is not None:
            up = estimate_up(cameras) if files is None else files_upright(cameras, files)
    if up is None and auto:
        return None, "the world's own frame: the scene's up is unknown (give --scene, or --y-up for the world's -y)"
    if up is None:
        return Y_UP, "y up: the world's -y (no cameras known; give --scene for the cameras' up)"
    counts = f"; {up.cameras} cameras, rms roll {up.rms_roll_deg:.1f} deg" if up.cameras else ""
    return engine_rotation(up), f"y up: the cameras' up, from {up.how}{counts}"


def _check_frame_flags(args):
    """One-line errors for lengths that are not positive and for flags that contradict each other;
    ``--origin ground`` and ``--camera-height`` turn ``--y-up`` on."""
    for flag, v in (("--scale", args.scale), ("--camera-height", args.camera_height)):
        if v is not None and not (np.isfinite(v) and v > 0):
            raise ExportError(f"{flag} {v:g}: expected a positive length factor")
    if args.scale is not None and args.camera_height is not None:
        raise ExportError("--scale and --camera-height both set the size; give one")
    if args.world_frame and (args.y_up or args.origin != "world" or args.camera_height is not None):
        raise ExportError("--world-frame keeps the world's frame, which --y-up, --origin ground and --camera-height "
                          "change; give one or the other")
    if args.origin != "world" or args.camera_height is not None:
        args.y_up = True


def _placement(args, model, rotation, cams):
    """``(frame: the 3x3 rotation or a 4x4 similarity, words)`` for ``--origin`` / ``--scale`` /
    ``--camera-height`` (:mod:`~tsplus_wgpu.apps.placement`)."""
    from ..apps.placement import PlacementError, engine_frame, find_placement
    if args.origin == "world" and args.scale is None and args.camera_height is None:
        return rotation, ""
    rot = np.eye(3) if rotation is None else rotation
    scale, origin, words = args.scale or 1.0, None, []
    what = _placing(args)
    if what:
        cameras, _ = cams()                         # raises when they cannot be had
        centers = np.array([c.center for c in cameras])
        dirs = np.array([c.R[2] for c in cameras])
        try:
            pl = find_placement(model.positions, model.triangles, centers, dirs, rot[1])
        except PlacementError as exc:
            raise ExportError(f"{what}: {exc}; give --origin world, and --scale for the size") from None
        words.append(f"the ground {pl.camera_height:.4g} world units below the {pl.cameras} cameras' median height "
                     f"({100 * pl.share:.0f} % of the level surface near them)")
        if args.origin == "ground":
            origin = pl.origin
            words.append(f"origin on the ground under {pl.middle}")
        if args.camera_height is not None:
            scale = args.camera_height / pl.camera_height
            words.append(f"scale {scale:.4g}: the cameras {args.camera_height:g} above the ground")
    if args.scale is not None:
        words.append(f"scale {scale:g}")
    return engine_frame(rot, origin, scale), "; ".join(words)


def run(args):
    model, info = load_run(args.run)
    fmt = args.format
    if fmt is None:
        fmt = Path(args.out).suffix.lstrip(".").lower() if args.out else "ply"
    fmt = fmt.lower()
    if fmt not in FORMATS:
        raise ExportError(f"--format {fmt or '(none)'}: unknown format; choose one of {', '.join(FORMATS)}")
    if model.num_triangles == 0:
        raise ExportError(f"{args.run}: the mesh has no triangles; nothing to export")
    run = Path(args.run)
    out = Path(args.out) if args.out else (run / f"mesh_export.{fmt}" if run.is_dir()
                                           else run.with_name(f"{run.stem}_export.{fmt}"))
    colors, source = info.get("colors"), "the mesh's colours"
    if args.bake == "dc" or colors is None or len(colors) != model.num_vertices:
        colors, source = None, "SH DC"
    if args.bake in ("fit", "views"):
        colors, source = _bake(args, model, info)
    _check_frame_flags(args)
    got = []

    def cams():
        if not got:
            got.append(_scene_cameras(args, info))
        return got[0]
    rotation, frame = _engine_frame(args, info, cams, auto=fmt == "glb" and not args.y_up and not args.world_frame)
    rotation, placed = _placement(args, model, rotation, cams)
    export(model, out, fmt=fmt, colors=colors, rotation=rotation)
    print(f"{info.get('from', 'model')}: {model.num_vertices} vertices, {model.num_triangles} triangles, SH "
          f"{model.sh_size} coefficients")
    print(connectivity_line(connectivity(model.triangles, model.num_vertices)))
    print(f"wrote {out} ({fmt}, {out.stat().st_size} bytes{', ' + frame if frame else ''}, colour from "
          f"{source})")
    if placed:
        print(f"placed: {placed}")
    return 0
