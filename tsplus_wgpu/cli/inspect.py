"""``tsplus inspect SCENE``: load a scene and print what was found.

Wired into the main command by :func:`add_parser` and :func:`run`;
``python -m tsplus_wgpu.cli.inspect SCENE`` runs it alone.
"""

from __future__ import annotations

import argparse
import sys


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Register the ``inspect`` sub-command on an argparse ``subparsers`` object."""
    p = subparsers.add_parser(
        "inspect", help="load a scene and print its format, cameras, images, points, split and warnings",
        description="Load a scene (COLMAP, transforms.json, LLFF, a folder of photos, a video, or 'procedural') "
                    "and print what was found. Data problems are reported in one line (exit status 2).")
    _add_arguments(p)
    p.set_defaults(func=run)
    return p


def _add_arguments(p):
    p.add_argument("scene", nargs="?", default="procedural",
                   help="scene folder, a video file, or 'procedural[:tiny|small|demo]' (default: procedural)")
    p.add_argument("--images", default=None, help="image folder name inside the scene (default: images)")
    p.add_argument("--downscale", type=float, default=1.0, help="shrink images by this factor (default 1)")
    p.add_argument("--background", default=None,
                   help="'white', 'black' or 'R,G,B' in [0,1] for RGBA images (default: per format)")
    p.add_argument("--split", default="auto", help="'auto' (default), 'none' or 'everyK'")
    p.add_argument("--points", default="auto", choices=("auto", "most", "triangulate", "frusta", "none"),
                   help="initial points (default auto: the SfM points; without them triangulated, else frusta); "
                        "most: what `tsplus train --points auto` starts from (the SfM points or the triangulated "
                        "ones, whichever are more)")
    p.add_argument("--strict", action="store_true", help="stop at the first missing or unreadable image")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--write-normals", default=None, metavar="DIR",
                   help="write the ground-truth normal map of every view to DIR (scenes with a ground-truth mesh: "
                        "the procedural scene), named like the views, in the convention of `tsplus train --normals`: "
                        "camera space, OpenCV axes (x right, y down, z forward), facing the camera, zero where no "
                        "surface is seen")
    p.add_argument("--normals-format", choices=("npy", "png"), default="npy",
                   help="--write-normals file format: npy (float32 [H, W, 3]) or png (16-bit RGBA, rgb = (n + 1) / 2, "
                        "alpha 0 where no surface); default npy")


def run(args) -> int:
    """Run ``inspect`` for parsed ``args``; returns the exit status (0 ok, 2 bad data)."""
    from ..data.errors import SceneError  # noqa: PLC0415
    from ..data.loader import load_scene  # noqa: PLC0415
    split = args.split
    if isinstance(split, str) and split.isdigit():
        split = int(split)
    try:
        scene = load_scene(args.scene, images=args.images, downscale=args.downscale, background=args.background,
                           split=split, points=args.points, on_bad_image="error" if args.strict else "skip",
                           progress=not args.quiet)
    except SceneError as exc:
        print(f"tsplus: error: {exc}", file=sys.stderr)
        return 2
    print(scene.summary())
    if getattr(args, "write_normals", None):
        if scene.gt_mesh is None:
            print(f"tsplus: error: --write-normals: {args.scene} has no ground-truth mesh (only the procedural "
                  "scene has one)", file=sys.stderr)
            return 2
        from ..data.normals import write_normal_maps  # noqa: PLC0415
        from ..data.procedural import normal_maps  # noqa: PLC0415
        paths = write_normal_maps(args.write_normals, scene, normal_maps(scene), args.normals_format)
        print(f"wrote {len(paths)} ground-truth normal maps ({args.normals_format}) to {args.write_normals}")
    return 0


def main(argv=None) -> int:
    """Stand-alone entry point: ``python -m tsplus_wgpu.cli.inspect SCENE``."""
    p = argparse.ArgumentParser(prog="tsplus inspect", description="Load a scene and print what was found.")
    _add_arguments(p)
    return run(p.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
