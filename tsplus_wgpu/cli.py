"""The ``tsplus`` command."""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

EXAMPLES = """\
examples:
  tsplus render                         render the built-in scene through the WGSL rasterizer
  tsplus render --size tiny --out /tmp/r
  tsplus bench-raster --json out/raster.json
  tsplus adapters                       list GPU adapters and their features
  tsplus inspect ../shared/data/cup     what a scene folder holds
  tsplus train --out runs/small         train on the built-in scene (add --preset quick --iterations 300)
  tsplus export runs/small --format glb --y-up   engine-ready mesh (ply|glb|obj)
  tsplus eval runs/small procedural:small        held-out PSNR/SSIM of the mesh as an engine draws it
  tsplus view runs/small                         fly through the result (window; --screenshot out.png --camera N headless)
  tsplus view runs/small --walk                  walk through it: gravity and collision against the mesh
  tsplus select runs/small --masks masks/        extract the masked object (object.ply/glb) and remove it
  tsplus train --out runs/live --view            watch training live in a window

environment:
  TSPLUS_ADAPTER   adapter to use (substring of its name; 'lavapipe' = Mesa's CPU driver)
  TSPLUS_DATA      folder of real scenes for tests and benchmarks (default ../shared/data)
"""


class UserError(Exception):
    """A mistake in the command line or the input data: printed as one line, exit 2."""


def _add_adapter(p):
    p.add_argument("--adapter", default=None,
                   help="GPU adapter to use, matched against its name (e.g. 'nvidia', 'lavapipe'); "
                        "default: TSPLUS_ADAPTER or the best one (discrete GPU first)")


def build_parser():
    parser = argparse.ArgumentParser(
        prog="tsplus", description="Triangle Splatting+ on any GPU through WebGPU/Vulkan (wgpu), or on the CPU "
                                   "with Mesa lavapipe.",
        epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    from . import __version__
    parser.add_argument("--version", action="version", version=f"tsplus-wgpu {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    p = sub.add_parser("render", help="render the built-in procedural scene's ground-truth mesh through the WGSL rasterizer",
                       description="Render the built-in procedural scene's ground-truth mesh (vertex colours, "
                                   "opaque) through the WGSL rasterizer from every camera, compare with the scene's "
                                   "reference images (PSNR) and print per-stage timings.")
    p.add_argument("--size", choices=["tiny", "small", "demo"], default="demo", help="scene size (default demo)")
    p.add_argument("--sigma", type=float, default=1e-4, help="window sharpness (default 1e-4: nearly opaque)")
    p.add_argument("--out", default="runs/render", help="output folder for images (default runs/render)")
    p.add_argument("--seed", type=int, default=0, help="scene seed (default 0)")
    _add_adapter(p)

    p = sub.add_parser("bench-raster", help="benchmark the forward rasterizer per stage against the device's peak",
                       description="Per-stage milliseconds (timestamp queries where supported), triangles/s and "
                                   "pixel-triangle evaluations/s for several triangle counts, with the device's peak "
                                   "FMA rate measured in the same run and the blend kernel's fraction of it.")
    p.add_argument("--triangles", nargs="+", default=["10000", "100000", "1000000"],
                   help="triangle counts (default 10000 100000 1000000)")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.add_argument("--sigma", type=float, default=0.5)
    p.add_argument("--repeats", type=int, default=5, help="timed runs per size; medians are reported (default 5)")
    p.add_argument("--json", default=None, help="write the full result as JSON here")
    _add_adapter(p)

    p = sub.add_parser("adapters", help="list the GPU adapters wgpu sees, with features and the chosen one")

    from .train.cli import add_train_parser
    add_train_parser(sub)
    from .evaluate import add_parsers as add_export_eval_parsers
    add_export_eval_parsers(sub)

    try:
        from .data import cli as data_cli
        data_cli.add_inspect_parser(sub)
    except ImportError:  # pragma: no cover
        pass
    from .viewer_cli import add_parsers as add_viewer_parsers
    add_viewer_parsers(sub)
    from .bench_report import add_parser as add_bench_parser
    add_bench_parser(sub)
    from .select import add_parser as add_select_parser
    add_select_parser(sub)
    try:
        from . import bench_backward  # noqa: F401  (its own parser: main() hands it the arguments)
        sub.add_parser("bench-backward", help="benchmark forward + backward per stage (tsplus bench-backward --help)",
                       add_help=False)
    except ImportError:
        pass
    return parser


def cmd_adapters(args):
    from .gpu import adapter_description, list_adapters, select_adapter
    adapters = list_adapters()
    if not adapters:
        from .gpu import LAVAPIPE_HINT
        raise UserError(LAVAPIPE_HINT)
    chosen = select_adapter(os.environ.get("TSPLUS_ADAPTER"))
    for a in adapters:
        mark = "*" if a is chosen or a.info == chosen.info else " "
        feats = set(a.features)
        opt = [name for key, name in (("timestamp-query", "timestamps"), ("shader-float32-atomic", "float32-atomics"),
                                      ("subgroup", "subgroups")) if key in feats]
        print(f"{mark} {adapter_description(a)}  [{', '.join(opt) or 'no optional features'}]")
    print("(* = used by default; set TSPLUS_ADAPTER or --adapter to choose)")
    return 0


def _demo_model(seed):
    """The procedural scene's ground-truth mesh as an opaque, vertex-coloured TriangleModel."""
    from .data import procedural
    from .reference import SH_C0
    from .types import TriangleModel
    verts, faces, fobj, objs = mesh = procedural.build_world(seed)
    face_of_vertex = np.zeros(len(verts), np.int64)
    face_of_vertex[faces.ravel()] = np.repeat(np.arange(len(faces)), 3)
    colors = procedural.surface_color(verts, face_of_vertex, mesh)
    sh = ((colors - 0.5) / SH_C0)[:, None, :]
    return TriangleModel(verts, faces, sh, np.ones(len(verts)))


def psnr(a, b):
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return float("inf") if mse == 0 else -10.0 * np.log10(mse)


def atomic_write_image(path, img):
    import imageio.v3 as iio
    path = Path(path)
    tmp = path.with_name(path.stem + ".tmp" + path.suffix)
    iio.imwrite(tmp, (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8))
    os.replace(tmp, path)


def cmd_render(args):
    from tqdm import tqdm

    from .data import load_procedural
    from .renderer import Renderer
    t0 = time.perf_counter()
    scene = load_procedural(args.size, seed=args.seed)
    t_scene = time.perf_counter() - t0
    model = _demo_model(args.seed)
    renderer = Renderer(args.adapter)
    print(f"adapter: {renderer.adapter_name}")
    print(f"scene: procedural '{args.size}' ({len(scene.cameras)} views, {scene.cameras[0].width}x"
          f"{scene.cameras[0].height}), mesh {model.num_vertices} vertices / {model.num_triangles} triangles "
          f"(built in {t_scene:.1f}s)")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    renderer.forward(model, scene.cameras[0], args.sigma).image   # warm-up: compile pipelines
    stage_ms, walls, psnrs = {}, [], []
    for i, cam in enumerate(tqdm(scene.cameras, desc="render", unit="view", dynamic_ncols=True)):
        t = time.perf_counter()
        res = renderer.forward(model, cam, args.sigma, profile=True)
        img = res.image
        walls.append(time.perf_counter() - t)
        for k, v in res.timings.items():
            stage_ms.setdefault(k, []).append(v)
        psnrs.append(psnr(img, scene.images[i]))
        if i < 4:
            atomic_write_image(out / f"view_{i:03d}.png", np.concatenate([scene.images[i], img], axis=1))
    print(f"{'stage':<20}{'median ms':>12}")
    for k, v in stage_ms.items():
        print(f"{k:<20}{np.median(v):>12.3f}")
    print(f"{'wall per view':<20}{1e3 * np.median(walls):>12.3f}")
    print(f"PSNR of the vertex-coloured mesh against the textured reference images: mean {np.mean(psnrs):.2f} dB "
          f"(min {np.min(psnrs):.2f}, max {np.max(psnrs):.2f})")
    print(f"wrote reference | render pairs to {out}/view_000.png ...")
    return 0


def main(argv=None):
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["bench-backward"]:      # a command with its own argument parser
        from . import bench_backward
        return bench_backward.main(argv[1:])
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    from .gpu import NoAdapterError
    try:
        from .data import SceneError
    except ImportError:  # pragma: no cover
        SceneError = UserError
    try:
        if args.command == "render":
            return cmd_render(args)
        if args.command == "bench-raster":
            from .bench import run_bench_raster
            return run_bench_raster(args)
        if args.command == "adapters":
            return cmd_adapters(args)
        if args.command == "train":
            from .train.cli import run_train
            return run_train(args)
        if args.command == "export":
            from .evaluate import run_export
            return run_export(args)
        if args.command == "eval":
            from .evaluate import run_eval
            return run_eval(args)
        if args.command == "view":
            from .viewer_cli import run_view
            return run_view(args)
        if args.command == "bench":
            from .bench_report import run_bench
            return run_bench(args)
        if args.command == "bench-viewer":
            from .viewer_cli import run_bench_viewer
            return run_bench_viewer(args)
        if args.command == "select":
            from .select import run_select
            return run_select(args)
        if args.command == "inspect":
            from .data import cli as data_cli
            return data_cli.run_inspect(args)
        parser.error(f"unknown command {args.command}")
    except (UserError, NoAdapterError, SceneError, ValueError, FileNotFoundError) as exc:
        print(f"tsplus: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("tsplus: interrupted", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
