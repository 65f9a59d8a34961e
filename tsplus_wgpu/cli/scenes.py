"""The scene a command names on its command line (``SCENE``, ``--images``, ``--downscale``),
loaded with the loader's warnings printed: shared by ``train``, ``eval``, ``view``, ``select``
and ``export`` (``inspect`` prints them in its summary)."""

from __future__ import annotations

import sys

from ..errors import UserError

IMAGES_HELP = ("image folder inside the scene (default: images; images_N when --downscale is N or when images/ is "
               "missing)")


def add_images_arg(p, help=IMAGES_HELP):
    """``--images DIR``: the image folder of the scene, as ``tsplus inspect`` takes it."""
    p.add_argument("--images", default=None, metavar="DIR", help=help)


#: ``--points`` of ``tsplus train`` -> ``load_scene``'s ``points``: the initial points
TRAIN_POINTS = {"auto": "most", "sfm": "auto", "triangulate": "triangulate", "frusta": "frusta"}
POINTS_CHOICES = tuple(TRAIN_POINTS)


def add_points_arg(p):
    """``--points auto|sfm|triangulate|frusta``: where ``tsplus train``'s initial points come from."""
    p.add_argument("--points", default="auto", choices=POINTS_CHOICES,
                   help="initial points: auto (the scene's SfM points or a triangulation with pycolmap from the "
                        "posed training images at full size, cached, whichever holds more points), sfm (the SfM "
                        "points; triangulated only when the scene has none), triangulate (always triangulated), "
                        "frusta (points spread in the cameras' frusta). All are meshed, except in the CPU adapter's "
                        "default run: at most half the vertex cap (--config's init_points_share)")


def is_procedural(scene_arg):
    return scene_arg is None or str(scene_arg).split(":")[0] == "procedural"


def print_scene_warnings(scene, file=None):
    """One ``warning: ...`` line per loader warning (skipped images, dropped points...)."""
    for w in getattr(scene, "warnings", None) or ():
        print(f"warning: {w}", file=file or sys.stderr, flush=True)


def load_cli_scene(scene_arg, downscale=1, seed=0, images=None, warn=True, points="auto", progress=False):
    """The scene ``scene_arg`` names (``procedural[:size]`` or a folder), its images from the
    folder ``images`` when given, its initial ``points`` as :func:`~tsplus_wgpu.data.loader.load_scene`
    takes them (``progress``: bars for its long steps); the loader's warnings printed (``warn``)
    and kept on ``scene.warnings`` for the run's config.json / metrics.json."""
    from ..data import load_scene_arg
    if is_procedural(scene_arg) and points not in ("auto", "most"):
        raise UserError(f"--points {points}: the procedural scene has its own points; drop --points")
    if is_procedural(scene_arg) and images is not None:
        raise UserError(f"--images {images}: the procedural scene has no image folder; drop --images")
    if is_procedural(scene_arg) or (images is None and points == "auto" and not progress):
        scene = load_scene_arg(scene_arg, downscale, seed)
    else:
        from ..data.loader import load_scene
        scene = load_scene(scene_arg, images=images, downscale=downscale, seed=seed, points=points,
                           progress=progress)
    if warn:
        print_scene_warnings(scene)
    return scene


def scene_warnings(scene):
    """The loader's warnings as a JSON-ready list."""
    return [str(w) for w in getattr(scene, "warnings", None) or ()]
