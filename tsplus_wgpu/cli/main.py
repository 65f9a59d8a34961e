"""The ``tsplus`` command: the parser, built from one command table, and the dispatch."""

from __future__ import annotations

import argparse
import errno
import importlib
import os
import sys

from ..errors import UserError

EXAMPLES = """\
examples:
  tsplus render                         render the built-in scene through the WGSL rasterizer
  tsplus render --size tiny --out /tmp/r
  tsplus bench-raster --json out/raster.json
  tsplus adapters                       list GPU adapters and their features
  tsplus inspect ../shared/data/cup     what a scene folder holds
  tsplus train capture.mp4 --out runs/c  train on a video's 100 sharpest frames (or: tsplus frames capture.mp4 --out DIR)
  tsplus train --out runs/small         train on the built-in scene (add --preset quick --iterations 300)
  tsplus export runs/small --format glb --y-up   engine-ready mesh (ply|glb|obj), upright on the cameras' up
  tsplus eval runs/small procedural:small        held-out PSNR/SSIM of the mesh as an engine draws it
  tsplus view runs/small                         fly through the result (window; --screenshot out.png --camera N headless)
  tsplus view runs/small --walk                  walk through it: gravity and collision against the mesh
  tsplus select runs/small --masks masks/        extract the masked object (object.ply/glb) and remove it
  tsplus train --out runs/live --view            watch training live in a window
  tsplus cache --clean                           free the cache of SfM models and points (what stopped jobs left)

environment:
  TSPLUS_ADAPTER   adapter to use (substring of its name; 'lavapipe' = Mesa's CPU driver)
  TSPLUS_DATA      folder of real scenes for tests and benchmarks (default ../shared/data)
  TSPLUS_DEBUG     1: show the traceback of an error too (for a bug report)
  TSPLUS_WEBGPU_LIMITS  1: WebGPU's default buffer sizes (128 MiB per binding), not the adapter's own
  TSPLUS_LAYOUT    cpu|gpu|pixel: the blend kernels' layout (default: cpu on a CPU adapter, gpu on any
                   other: the pixel forward with the column backward)
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
    "frames": ("frames", "add_parser"),
    "view": ("view", "add_parser"),
    "bench-viewer": ("bench_viewer", "add_parser"),
    "bench": ("bench", "add_bench_parser"),
    "select": ("select", "add_parser"),
    "bench-backward": ("bench", "add_backward_parser"),
    "bench-scale": ("bench", "add_scale_parser"),
    "bench-step": ("bench", "add_step_parser"),
    "cache": ("cache", "add_parser"),
}


def command_module(name):
    """The module of the ``tsplus`` command ``name``."""
    return importlib.import_module(f".{COMMANDS[name][0]}", __package__)


class Parser(argparse.ArgumentParser):
    """argparse with a one-line error (``tsplus: error: train: ...; see `tsplus train --help```)
    instead of the usage block; sub-parsers inherit it."""

    def error(self, message):
        sub = self.prog.split(" ", 1)[1] + ": " if " " in self.prog else ""
        print(f"tsplus: error: {sub}{message}; see `{self.prog} --help`", file=sys.stderr)
        self.exit(2)


def build_parser():
    parser = Parser(
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
    from ..data.long_calls import restore_signals, stop_on_signals
    from ..gpu.context import NoAdapterError
    try:
        from ..data.sfm import sfm_focal, sfm_threads
        sfm_threads()   # a bad TSPLUS_SFM_THREADS is an error at the start, not after loading a scene
        sfm_focal()     # and TSPLUS_SFM_FOCAL
        old = stop_on_signals()   # SIGTERM, SIGHUP: one line as for Ctrl-C, never COLMAP's crash report
        try:
            return command_module(args.command).run(args)
        finally:
            restore_signals(old)
    except (UserError, NoAdapterError, SceneError, ValueError, OSError, MemoryError) as exc:
        line = error_line(exc)
        if line is None:                # not the user's or the environment's doing: a bug, with its traceback
            raise
        if os.environ.get("TSPLUS_DEBUG"):
            import traceback
            traceback.print_exc()
        print(f"tsplus: error: {line}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        return _interrupted(exc)


def _interrupted(exc) -> int:
    """Ctrl-C, or SIGTERM / SIGHUP outside the training steps (:class:`~tsplus_wgpu.data.long_calls.Stopped`):
    one line and the exit status 128 + the signal."""
    import signal
    signum = getattr(exc, "signum", None) or signal.SIGINT
    print(f"tsplus: {'interrupted' if signum == signal.SIGINT else f'stopped by {signal.Signals(signum).name}'}",
          file=sys.stderr)
    return 128 + int(signum)


#: errno -> (what happened, what to do) for a file the command read or wrote
OS_CAUSES = {
    errno.ENOSPC: ("no space left on the device", "free some space or write elsewhere (--out)"),
    errno.EDQUOT: ("disk quota exceeded", "free some space or write elsewhere (--out)"),
    errno.EROFS: ("the file system is read-only", "write elsewhere (--out)"),
    errno.EACCES: ("permission denied", "fix the permissions or use another path"),
    errno.EPERM: ("operation not permitted", "fix the permissions or use another path"),
    errno.ENOENT: ("no such file or folder", "check the path"),
    errno.ENOTDIR: ("a part of the path is a file, not a folder", "check the path"),
    errno.EISDIR: ("is a folder, not a file", "give a file"),
    errno.EEXIST: ("already exists (a file where a folder is needed?)", "remove it or use another path"),
    errno.ENAMETOOLONG: ("the name is too long", "use a shorter path"),
    errno.ELOOP: ("too many levels of symbolic links", "check the path"),
    errno.EIO: ("input/output error", "check the disk"),
    errno.EMFILE: ("too many open files", "raise the limit (ulimit -n) or close other programs"),
    errno.ENFILE: ("too many open files in the system", "close other programs"),
    errno.ENOMEM: ("out of memory", "free memory or use a smaller scene (--downscale)"),
}


def error_line(exc):
    """The one line ``tsplus`` prints for ``exc`` (no ``tsplus: error:`` prefix), or None when
    ``exc`` is a bug that should show its traceback."""
    if isinstance(exc, UnicodeDecodeError):
        return (f"a file is not UTF-8 text ({exc.reason} at byte {exc.start}); check the file the command reads "
                f"(--config, transforms.json, ...) and save it as UTF-8")
    if isinstance(exc, MemoryError):
        detail = f" ({exc})" if str(exc) else ""
        return (f"out of memory{detail}; use smaller settings (--downscale, --max-vertices, --iterations) or a "
                f"machine with more memory")
    if isinstance(exc, OSError) and not isinstance(exc, UserError) and exc.errno is not None:
        return _os_error_line(exc)
    return str(exc) or type(exc).__name__


def _os_error_line(exc):
    """``FILE: what happened; what to do`` of an :class:`OSError` from the system (disk full,
    read-only, permission, missing path...); None for one without a file or a known cause."""
    names = [os.fsdecode(n) for n in (exc.filename, exc.filename2) if n is not None]
    where = " -> ".join(names)
    cause, fix = OS_CAUSES.get(exc.errno, (None, None))
    if cause is None:
        if not where:
            return None
        cause, fix = exc.strerror or str(exc), "check the path and the disk"
    return f"{where + ': ' if where else ''}{cause}; {fix}"


if __name__ == "__main__":
    sys.exit(main())
