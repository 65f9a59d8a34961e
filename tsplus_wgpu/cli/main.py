"""The ``tsplus`` command: the parser, built from one command table, and the dispatch."""

from __future__ import annotations

import argparse
import importlib
import sys

from ..errors import UserError

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


#: command -> (module of this package, its function that adds the command's sub-parser), in the
#: order ``tsplus --help`` lists them; each module's ``run(args)`` runs its command(s)
COMMANDS = {
    "render": ("render", "add_parser"),
    "bench-raster": ("bench", "add_raster_parser"),
    "adapters": ("adapters", "add_parser"),
    "train": ("train", "add_parser"),
    "export": ("export", "add_parser"),
    "eval": ("eval", "add_parser"),
    "inspect": ("inspect", "add_parser"),
    "view": ("view", "add_parser"),
    "bench-viewer": ("bench_viewer", "add_parser"),
    "bench": ("bench", "add_bench_parser"),
    "select": ("select", "add_parser"),
    "bench-backward": ("bench", "add_backward_parser"),
}


def command_module(name):
    """The module of the ``tsplus`` command ``name``."""
    return importlib.import_module(f".{COMMANDS[name][0]}", __package__)


def build_parser():
    parser = argparse.ArgumentParser(
        prog="tsplus", description="Triangle Splatting+ on any GPU through WebGPU/Vulkan (wgpu), or on the CPU "
                                   "with Mesa lavapipe.",
        epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    from .. import __version__
    parser.add_argument("--version", action="version", version=f"tsplus-wgpu {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (_, add) in COMMANDS.items():
        getattr(command_module(name), add)(sub)
    return parser


def main(argv=None):
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    from ..data.errors import SceneError
    from ..gpu.context import NoAdapterError
    try:
        return command_module(args.command).run(args)
    except (UserError, NoAdapterError, SceneError, ValueError, FileNotFoundError) as exc:
        print(f"tsplus: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("tsplus: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
