"""``tsplus inspect SCENE``: load a scene and print what was found.

Wire into the main command with :func:`add_inspect_parser` and :func:`run_inspect`;
``python -m tsplus_wgpu.data.cli SCENE`` runs it alone.
"""

from __future__ import annotations

import argparse
import sys


def add_inspect_parser(subparsers) -> argparse.ArgumentParser:
    """Register the ``inspect`` sub-command on an argparse ``subparsers`` object."""
    p = subparsers.add_parser(
        "inspect", help="load a scene and print its format, cameras, images, points, split and warnings",
        description="Load a scene (COLMAP, transforms.json, LLFF, a folder of photos, or 'procedural') "
                    "and print what was found. Data problems are reported in one line (exit status 2).")
    _add_arguments(p)
    p.set_defaults(func=run_inspect)
    return p


def _add_arguments(p):
    p.add_argument("scene", nargs="?", default="procedural",
                   help="scene folder, or 'procedural[:tiny|small|demo]' (default: procedural)")
    p.add_argument("--images", default=None, help="image folder name inside the scene (default: images)")
    p.add_argument("--downscale", type=float, default=1.0, help="shrink images by this factor (default 1)")
    p.add_argument("--background", default=None,
                   help="'white', 'black' or 'R,G,B' in [0,1] for RGBA images (default: per format)")
    p.add_argument("--split", default="auto", help="'auto' (default), 'none' or 'everyK'")
    p.add_argument("--points", default="auto", choices=("auto", "triangulate", "frusta", "none"),
                   help="initial points when the scene has none (default auto: triangulate, else frusta)")
    p.add_argument("--strict", action="store_true", help="stop at the first missing or unreadable image")
    p.add_argument("--quiet", action="store_true", help="no progress bars")


def run_inspect(args) -> int:
    """Run ``inspect`` for parsed ``args``; returns the exit status (0 ok, 2 bad data)."""
    from .errors import SceneError  # noqa: PLC0415
    from .loader import load_scene  # noqa: PLC0415
    split = args.split
    if isinstance(split, str) and split.isdigit():
        split = int(split)
    try:
        scene = load_scene(args.scene, images=args.images, downscale=args.downscale, background=args.background,
                           split=split, points=args.points, on_bad_image="error" if args.strict else "skip",
                           progress=not args.quiet)
    except SceneError as exc:
        print(f"tsplus inspect: error: {exc}", file=sys.stderr)
        return 2
    print(scene.summary())
    return 0


def main(argv=None) -> int:
    """Stand-alone entry point: ``python -m tsplus_wgpu.data.cli SCENE``."""
    p = argparse.ArgumentParser(prog="tsplus inspect", description="Load a scene and print what was found.")
    _add_arguments(p)
    return run_inspect(p.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
