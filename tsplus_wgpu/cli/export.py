"""``tsplus export``: write a trained run (or a mesh, or a checkpoint) as PLY / GLB / OBJ."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..apps.runs import load_run
from ..io.export import BAKES, FORMATS, ExportError, bake_views, connectivity, connectivity_line, export
from .scenes import add_images_arg, load_cli_scene


def add_parser(sub):
    p = sub.add_parser("export", help="write a trained run (or a mesh) as PLY / GLB / OBJ",
                       description="Write RUN (a folder written by `tsplus train`, a .ply/.glb/.obj mesh or a "
                                   "checkpoint .npz) as PLY (float32 positions, uint8 RGB, full SH and opacity as "
                                   "extra vertex properties; reads back losslessly), GLB (glTF 2.0 with COLOR_0) or "
                                   "OBJ (vertex colours). Written atomically; prints the connectivity report.")
    p.add_argument("run", help="run folder, mesh file or checkpoint")
    p.add_argument("--format", default=None, help="ply, glb or obj (default: --out's extension, else ply)")
    p.add_argument("--out", default=None, help="output file (default: RUN/mesh_export.FORMAT, or beside the mesh)")
    p.add_argument("--y-up", action="store_true", help="convert the OpenCV world (y down) to y up: (x, -y, -z)")
    p.add_argument("--bake", choices=BAKES, default="dc",
                   help="vertex colour: dc (SH DC term, default) or views (averaged over the training views where "
                        "the vertex is visible; needs the run's scene or --scene)")
    p.add_argument("--scene", default=None, help="scene for --bake views (default: the run's)")
    add_images_arg(p, help="image folder inside the scene for --bake views (default: the run's, else images)")
    p.add_argument("--adapter", default=None, help="GPU adapter to use (substring of its name)")
    return p


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
    colors = None
    if args.bake == "views":
        scene_arg = args.scene or info.get("scene")
        if not scene_arg:
            raise ExportError("--bake views: the run names no scene; give --scene")
        images = args.images or (None if args.scene else info.get("images"))
        scene = load_cli_scene(scene_arg, int(info.get("downscale") or 1) if not args.scene else 1, 0, images)
        from ..render.mesh_renderer import MeshRenderer
        mr = MeshRenderer(args.adapter)
        t0 = time.perf_counter()
        colors, seen = bake_views(model, scene, mesh_renderer=mr)
        print(f"baked colours from {len(scene.train_indices or scene.cameras)} training views on {mr.adapter_name} "
              f"in {time.perf_counter() - t0:.1f}s ({100 * np.mean(seen > 0):.1f}% of vertices seen; the others keep "
              f"SH DC)")
    export(model, out, fmt=fmt, colors=colors, y_up=args.y_up)
    print(f"{info.get('from', 'model')}: {model.num_vertices} vertices, {model.num_triangles} triangles, SH "
          f"{model.sh_size} coefficients")
    print(connectivity_line(connectivity(model.triangles, model.num_vertices)))
    print(f"wrote {out} ({fmt}, {out.stat().st_size} bytes{', y up' if args.y_up else ''}, colour from "
          f"{'training views' if args.bake == 'views' else 'SH DC'})")
    return 0
