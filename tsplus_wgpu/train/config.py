"""Everything that determines a training run: :class:`TrainConfig`.

Each field is declared once, with its default, its help text and (for the settings
``tsplus train`` exposes) its command-line flag in the field's metadata; ``cli/train.py`` builds
its options from :func:`cli_options`, so the library and the command cannot disagree on a
default. A field whose default differs under ``--preset quick`` names that value as well
(``quick=``); :meth:`TrainConfig.preset` applies it. Each field also names its ``check``: the
type and range it accepts, enforced in one place (:func:`check_settings`) for the library
(``TrainConfig(...)`` raises), a ``--config`` file and the command-line flags alike.
"""

from __future__ import annotations

import difflib
import json
import math
import numbers
import os
from dataclasses import MISSING, dataclass, field, fields
from pathlib import Path

from ..data.frame import NEAR
from ..errors import UserError
from .schedules import OPACITY_MODES, SH_DEGREE_MAX, SIGMA_FINAL, Schedule

#: the most iterations a run may have (333 x the paper's 30000; more is a typo, not a plan)
MAX_ITERATIONS = 10_000_000
#: the largest densification cap (vertex indices are 32-bit on the GPU)
MAX_VERTICES = 2**31 - 1
#: seeds are unsigned 32-bit (numpy's default_rng([seed, epoch]))
MAX_SEED = 2**32 - 1


class ConfigError(UserError, ValueError):
    """A training setting of the wrong type or out of range, or an unknown key: one line
    naming the field (or flag, or config file and key) and what it accepts."""


def option(default=MISSING, help="", flag=None, quick=None, default_factory=MISSING, check=None, absent=MISSING,
           **argparse):
    """A :class:`TrainConfig` field: ``default`` (or ``default_factory``), ``help`` (one
    sentence, no default in it: the CLI appends that), ``flag`` (the ``tsplus train`` option,
    None: config files only), ``quick`` (the default under ``--preset quick`` when it differs),
    ``check`` (a :mod:`.checks` checker: the accepted type and range), ``absent`` (what a
    checkpoint written before the field existed trained with, where that is not ``default``) and
    further ``argparse`` keywords for the flag (``type``, ``metavar``, ``choices``...)."""
    meta = dict(help=help, flag=flag, quick=quick, check=check, argparse=argparse)
    if absent is not MISSING:
        meta["absent"] = absent
    if default_factory is not MISSING:
        return field(default_factory=default_factory, metadata=meta)
    return field(default=default, metadata=meta)


class _Check:
    """A field's accepted values: ``expected`` (words for the error line) and ``convert(value)``
    (the value in its canonical type; ``ValueError`` when it is not accepted). ``on_disk``
    (``(expected, accept)``): a further check of the file system, made for the command line and
    config files (``disk=True``), not for the library (a config read back from a checkpoint)."""

    def __init__(self, expected, accept, convert=lambda v: v, on_disk=None):
        self.expected, self._accept, self._convert, self._on_disk = expected, accept, convert, on_disk

    def convert(self, value, disk=False):
        for expected, accept in [(self.expected, self._accept)] + ([self._on_disk] if disk and self._on_disk else []):
            try:
                ok = bool(accept(value))
            except (TypeError, ValueError):
                ok = False
            if not ok:
                raise ValueError(expected)
        return self._convert(value)


def _range_text(lo, hi, lo_open=False):
    def num(x):
        return f"{x:g}" if isinstance(x, float) else str(x)
    if hi is None:
        return f"{'>' if lo_open else '>='} {num(lo)}"
    return f"in {'(' if lo_open else '['}{num(lo)}, {num(hi)}]"


def _is_int(v):
    return isinstance(v, numbers.Integral) and not isinstance(v, bool)


def _is_real(v):
    return isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v)


def integer(lo, hi=None):
    """An integer (not a bool, not 1.5) in ``[lo, hi]`` (``hi`` None: no upper bound)."""
    return _Check(f"an integer {_range_text(lo, hi)}", lambda v: _is_int(v) and lo <= v and (hi is None or v <= hi),
                  int)


def real(lo, hi=None, lo_open=False):
    """A finite number in ``[lo, hi]`` (``(lo, hi]`` with ``lo_open``), returned as a float."""
    return _Check(f"a finite number {_range_text(lo, hi, lo_open)}",
                  lambda v: _is_real(v) and (v > lo if lo_open else v >= lo) and (hi is None or v <= hi), float)


def boolean():
    return _Check("true or false", lambda v: isinstance(v, bool) or (type(v).__module__ == "numpy" and type(v).__name__ in ("bool", "bool_")),
                  bool)


def choice(*values):
    return _Check("one of " + ", ".join(repr(c) for c in values), lambda v: isinstance(v, str) and v in values)


def rgb():
    """Three finite numbers in [0, 1] (a list or tuple), returned as a tuple of floats."""
    return _Check("three numbers in [0, 1] (R, G, B)",
                  lambda v: isinstance(v, (list, tuple)) and len(v) == 3 and all(_is_real(x) and 0 <= x <= 1
                                                                                  for x in v),
                  lambda v: tuple(float(x) for x in v))


def optional_path():
    return _Check("a folder path (or none)", lambda v: v is None or isinstance(v, (str, os.PathLike)) and str(v) != "",
                  lambda v: None if v is None else os.fspath(v),
                  on_disk=("an existing folder (or none)", lambda v: v is None or os.path.isdir(v)))


def mapping():
    return _Check("a table of notes", lambda v: isinstance(v, dict), dict)


@dataclass
class TrainConfig:
    """Everything that determines a run (written to ``config.json``, stored in checkpoints).
    The help text of every field is in its metadata (``tsplus train --help`` shows it); the
    ablation switches ``hard_prune``, ``weight_prune``, ``sigma_decay``, ``sigma_final`` and
    ``opacity`` are the paper's Tables 2-3 (:class:`~.schedules.Schedule` documents each,
    ``ablations.ABLATIONS`` names the rows)."""

    iterations: int = option(30000, "optimisation steps (the paper: 30000; tsplus train on a CPU adapter without --preset: 600-3000, as many as fit about 11 minutes of training on 2 cores)", flag="--iterations", quick=3000,
                             check=integer(1, MAX_ITERATIONS), type=int)
    quick: bool = option(False, "scale every schedule's iteration constants to `iterations` (--preset quick)", check=boolean())
    indoor: bool = option(False, "the indoor constants of method.md", flag="--indoor", check=boolean(),
                          action="store_const", const=True)
    seed: int = option(0, "seed of the view order (nothing else is random)", flag="--seed",
                     check=integer(0, MAX_SEED), type=int)
    sh_degree: int = option(3, "SH degree of the model's storage (the schedule raises the trained degree "
                               "up to it); the exported mesh keeps only degree 0 (vertex colours)",
                            flag="--sh-degree", check=integer(0, SH_DEGREE_MAX), type=int)
    background: tuple = option((0.0, 0.0, 0.0), "RGB behind the triangles (tsplus train: the scene's)",
                               check=rgb())
    near: float = option(NEAR, "near plane, in units of the camera radius (the scene is trained in a normalised frame)",
                         check=real(0.0, lo_open=True))
    log_every: int = option(100, "iterations between log lines (host readback only then; 0: none)",
                            flag="--log-every", quick=25, check=integer(0), type=int)
    checkpoint_every: int = option(1000, "iterations between checkpoints (0: only at the end or on Ctrl-C)",
                                   flag="--checkpoint-every", check=integer(0),
                                   type=int)
    opacity_reg: bool = option(True, "apply the early opacity loss of method.md", check=boolean())
    topology: bool = option(
        True, "pruning and densification during training (the final cleanup runs either way). The quick preset "
              "keeps at least 3 epochs between topology events and a 10x opacity learning rate (config keys "
              "quick_topology_epochs, quick_opacity_lr_scale) so that opacities separate before a prune. Measured "
              "on procedural:small, quick, 3000 iterations: held-out mesh PSNR 25.56 dB with topology vs 22.14 dB "
              "without; on runs of a few hundred iterations on a tiny scene it does not pay off (tiny, 600: 20.91 "
              "on vs 21.92 dB off): use off there", flag="--topology", check=boolean(), choices=["on", "off"])
    max_vertices: int = option(3_000_000, "densification cap (method.md)", flag="--max-vertices",
                               check=integer(0, MAX_VERTICES), type=int)
    vertex_budget: float = option(
        2.0, "densification cap per training pixel: the model grows to at most min(max_vertices, ceil(F x P)) "
             "vertices, P the mean pixel count of a training image at the training resolution (0: no budget). A "
             "model should not outgrow what its images can constrain: the paper's 3M cap is about 2 vertices per "
             "pixel of its ~1.6k x 1k training images (its scenes end near 2M); without a budget, lund at "
             "--downscale 4 (42k pixels per image) grew past 15 vertices per pixel by iteration 1100 and hit the "
             "storage-binding limit", flag="--vertex-budget", check=real(0.0), type=float, metavar="F")
    init_points_share: float = option(
        0.0, "the initial mesh is built from at most this share of the densification cap in points (those seen "
             "by 3 or more views first, a fixed random choice within; 0: all). 0 (every point) unless the CPU "
             "adapter's plan picks the iterations: that plan meshes at most 0.5 x the cap's points, since every "
             "point costs a CPU run iterations (the initial mesh's Delaunay faces, about 12 a point, are drawn "
             "until the first prune; the cup's default run: 24.57 dB at 0.5 and 1,700 iterations, 23.37 with "
             "every point and the 1,100 that then fit). Where time does not bind, every point wins: at a quarter "
             "of the CPU default's pixels and 2,000 quick iterations, 0.5 -> every point gives cup 24.74 -> "
             "25.81, office 24.27 -> 25.62, fox 24.57 -> 26.19 dB (lund meshes all its points either way), "
             "with 17-21 % of the fixed schedule's vertices (docs/measurements.md)",
        check=real(0.0, 1.0))
    densify_stop_rel: float = option(
        0.01, "stop densifying when the mean training L1 of the last 3 topology windows is within this fraction "
              "of the 3 before, up or down (flat; a larger rise is the schedule's doing, not a plateau) (0: never)",
        flag="--densify-stop", check=real(0.0, 1.0), type=float,
        metavar="DENSIFY_STOP")
    densify_stop_windows: int = option(3, "K of the densification stop: windows in each of the two compared means",
                                      check=integer(1))
    quick_topology_epochs: float = option(
        3.0, "with quick, at least this many epochs (passes over the training views) between topology events, so "
             "the first prune comes after the opacities have had time to separate and every weight prune sees "
             "every view", check=real(0.0))
    quick_early_prune: bool = option(
        True, "with quick, the topology steps before the first prune step also prune by opacity (the hard prune's "
              "test, shell exempt): most initial Delaunay faces have lost their opacity by then, and the steps up to "
              "the hard prune no longer draw them (the cup's default run: 248,588 of 357,349 triangles at iteration "
              "229, training 7 % shorter; docs/measurements.md)", flag="--early-prune", check=boolean(),
        absent=False, choices=["on", "off"])
    quick_opacity_lr_scale: float = option(
        10.0, "with quick, the opacity learning rate is multiplied by this (a 300-iteration run has 1/100 of the "
              "paper's steps: at 0.03 a logit moves at most 1.2 before the first scaled prune)", check=real(0.0, lo_open=True))
    shell: bool = option(
        True, "add a background shell to the initial mesh: a sphere around the cameras (5 camera radii, or beyond "
              "the points), cut to what the training views see and coloured from them, exempt from the opacity and "
              "weight prunes, so pixels SfM found no points for are covered (tsplus_wgpu/train/shell.py)",
        flag="--shell", check=boolean(), choices=["on", "off"])
    init_max_edge: float = option(
        3.0, "drop initial Delaunay faces whose longest edge exceeds this many local point spacings (distance to "
             "the 8th nearest point): the faces that span free space and train into shards (0: keep all)",
        flag="--init-max-edge", check=real(0.0), type=float)
    view_faces: bool = option(
        False, "add to the initial Delaunay faces those of each training view's 2-D Delaunay triangulation of the points "
               "it observed (the points next to each other in that photo; needs the points' tracks). Off by default: "
               "+0.18 dB on lund's forward walk, nothing or a loss on the other shared scenes "
               "(tsplus_wgpu/train/init.py; docs/measurements.md)", flag="--view-faces", check=boolean(), absent=False,
        choices=["on", "off"])
    position_lr_depth: bool = option(
        True, "scale each vertex's position learning rate by min(1, its distance to the nearest training camera in "
              "camera radii), read before every step: Adam moves a vertex by about the rate whatever its depth, so "
              "geometry near the cameras jumped many pixels a step and turned into shards "
              "(tsplus_wgpu/train/optimizer.py; docs/measurements.md)", flag="--position-lr-depth", check=boolean(),
        absent=False, choices=["on", "off"])
    clear_path: bool = option(
        True, "drop the initial Delaunay faces within half the median camera spacing of the path the training cameras "
              "moved along: the photographer walked through that space, so it is empty (tsplus_wgpu/train/floaters.py; "
              "lund's 600-iteration runs +0.4 dB held out over the same removal at the end alone, +0.05 at 3,000)",
        flag="--clear-path", check=boolean(), choices=["on", "off"])
    carve: bool = option(
        False, "carve the initial Delaunay mesh with the SfM tracks: drop the faces that a segment from a training "
               "camera to a point it observed crosses (free space; tsplus_wgpu/train/carve.py). Off by default: "
               "measured +0.4/+0.8 dB on fox/lund but -0.6/-0.2 dB on cup/office (docs/measurements.md)",
        flag="--carve", check=boolean(), choices=["on", "off"])
    final_prune: bool = option(
        False, "on: the end of training deletes the triangles no training view sees with a blending weight above "
               "0.5 (the paper's cleanup, method.md); off keeps those hidden triangles in the exported mesh, where "
               "other viewpoints see them (docs/training.md#end-of-training)", flag="--final-prune", check=boolean(),
        choices=["on", "off"])
    fill_holes: bool = option(
        True, "at the end, add the triangles of a fresh background shell that a training view shows through a hole "
              "of the exported mesh (where nothing is drawn), so the mesh covers every training view "
              "(tsplus_wgpu/train/final.py; held-out coverage 92.7 -> 99.9 percent on office)", flag="--fill-holes",
        check=boolean(), choices=["on", "off"])
    fill_hidden: bool = option(
        True, "with --fill-holes on: the fill also covers what the trained background shell lost behind the surfaces "
              "(its triangles hidden in every training view are deleted during training), lying just beyond it, so "
              "viewpoints between and beside the training views see a backdrop past the surfaces' edges instead of "
              "nothing (tsplus_wgpu/train/final.py)", flag="--fill-hidden", check=boolean(), choices=["on", "off"])
    remove_shards: bool = option(
        True, "at the end, remove the shards of the exported mesh (surface triangles larger than 0.15 rad from the "
              "nearest training camera whose pixels' error is over twice the mean, and those within half the median "
              "camera spacing of the path the training cameras moved along), then fill and colour again "
              "(tsplus_wgpu/train/final.py, floaters.py; +0.2 to +0.9 dB held-out on the four shared real captures, "
              "the path another +0.5 to +1.3 dB on lund)",
        flag="--remove-shards", check=boolean(), choices=["on", "off"])
    shard_check: bool = option(
        True, "with --remove-shards on: put back the shards (by size and error; not the path's floaters or the far "
              "field's) whose pixels the training views draw worse without them (the mesh exported again without "
              "every removed one, its fill and colours made again; tsplus_wgpu/train/final.py): a near surface the "
              "photos show in detail is imperfect, but better than what lies behind it", flag="--shard-check",
        check=boolean(), choices=["on", "off"])
    remove_far: bool = option(
        True, "with --remove-shards on: also remove the surface triangles in front of what the training photos show "
              "far away (the sky): a pixel whose neighbouring views match it better along its direction alone than "
              "at the mesh's depth there is far, and a triangle that draws mostly such pixels goes "
              "(tsplus_wgpu/train/far_field.py; docs/measurements.md)",
        flag="--remove-far", check=boolean(), choices=["on", "off"])
    remove_sky: bool = option(
        True, "with --remove-shards on: also remove the surface triangles whose pixels in the training photos are "
              "mostly sky (smooth, blue, above the horizon, reaching the frame), so the backdrop draws the "
              "sky far away (tsplus_wgpu/train/sky.py; docs/measurements.md)",
        flag="--remove-sky", check=boolean(), choices=["on", "off"])
    color_detail: bool = option(
        True, "at the end, subdivide the exported mesh where its triangles are large on screen (over 16, 8, 4 or 2 "
              "pixels, within --detail-budget) so the fitted vertex colours carry the photos' texture; the level is "
              "the one whose colours, fitted without every 4th training view, draw those views best (none if the "
              "mesh as trained does; tsplus_wgpu/train/detail.py). Needs --mesh-colors fit",
        flag="--color-detail", check=boolean(), choices=["on", "off"])
    detail_budget: float = option(
        8.0, "vertices per training pixel the colour detail may bring the exported mesh to (within "
             "--max-vertices, never below the training cap --vertex-budget; 0: that cap). Only the export is "
             "subdivided, so this is not a bound on what training can constrain: each vertex colour is fitted to "
             "every training view, and the held-back views decide how much of it is used. 8 against 2 on the four "
             "shared real captures' default runs: +0.00 to +0.55 dB held-out, never worse",
        flag="--detail-budget", check=real(0.0), type=float, metavar="F")
    mesh_colors: str = option(
        "fit", "vertex colours of the exported mesh: 'fit' solves for the colours that best reproduce the training "
               "photos through the exported, depth-tested mesh (linear least squares, tsplus_wgpu/render/"
               "mesh_fit.py; +0.6 to +1.2 dB held-out on the four shared real captures); 'dc' takes the SH DC term",
        flag="--mesh-colors", check=choice("fit", "dc"), choices=["fit", "dc"])
    hard_prune: bool = option(True, "ablation: False drops the opacity criterion of pruning",
                             check=boolean())
    weight_prune: bool = option(True, "ablation: False drops the blending-weight criterion of pruning",
                               check=boolean())
    sigma_decay: bool = option(True, "ablation: False trains at sigma_final throughout", check=boolean())
    sigma_final: float = option(SIGMA_FINAL, "ablation: final sigma, 0.0001 (hard) or 0.1 (soft)",
                                check=real(0.0, 1.0, lo_open=True))
    opacity: str = option("opaque", "ablation: 'opaque' (the floor ramps to 0.9999) or 'free' (no floor)",
                        check=choice(*OPACITY_MODES))
    normals: str | None = option(
        None, "normal-map priors: add the normal loss 0.05 (indoor 0.025) * mean(1 - <N_rendered, N_prior>) for "
              "iterations > 5000 (scaled with --preset quick) on the training views that have a map (off without "
              "--normals; views without a map get none, the count is printed). One file per view named like its "
              "image with .npy (float [H, W, 3], the normal) or .png (8/16-bit, rgb = (n + 1) / 2, alpha 0 = no "
              "prior); normals in the view's camera space, OpenCV axes (x right, y down, z forward), facing the "
              "camera (z mostly < 0); pixels whose normal is (near) zero, black or masked are ignored; other sizes "
              "are area-resized with a warning. `tsplus inspect procedural:tiny --write-normals DIR` writes the "
              "procedural scene's true maps", flag="--normals", check=optional_path(), metavar="DIR")
    extra: dict = option(help="free-form notes stored with the run (scene, downscale, ablation...)",
                         default_factory=dict, check=mapping())

    def __post_init__(self):
        """Check every field (:func:`check_settings`): a :class:`ConfigError` naming the field
        and its flag for a value of the wrong type or out of range."""
        for name, value in check_settings({f.name: getattr(self, f.name) for f in fields(self)}).items():
            setattr(self, name, value)

    def schedule(self, views=1):
        return Schedule(total=int(self.iterations), indoor=bool(self.indoor), quick=bool(self.quick),
                        views=int(views), topology_epochs=float(self.quick_topology_epochs),
                        opacity_lr_scale=float(self.quick_opacity_lr_scale), hard_prune=bool(self.hard_prune),
                        early_prune=bool(self.quick_early_prune),
                        weight_prune=bool(self.weight_prune), sigma_decay=bool(self.sigma_decay),
                        sigma_final=float(self.sigma_final), opacity_mode=str(self.opacity))

    @classmethod
    def preset(cls, quick=False, **overrides):
        """A config with the defaults of ``--preset quick`` (``quick=True``) or ``paper``, then
        ``overrides``: what ``tsplus train`` builds."""
        return cls(**{**preset_defaults(quick), **overrides})

    #: fields that must match for ``--resume`` (the others may change between sessions)
    RESUME_KEYS = ("iterations", "quick", "indoor", "seed", "sh_degree", "background", "near", "opacity_reg",
                   "topology", "max_vertices", "vertex_budget", "densify_stop_rel", "densify_stop_windows",
                   "quick_topology_epochs", "quick_early_prune", "quick_opacity_lr_scale", "shell", "init_max_edge", "carve", "hard_prune",
                   "weight_prune", "sigma_decay", "sigma_final", "opacity", "normals", "position_lr_depth",
                   "view_faces")


def _label(f, source):
    """How an error names field ``f``: by its flag (``source`` "flags"), as a key of a config
    file (``source`` that file's label), or as the field with its flag (``source`` None)."""
    flag = f.metadata.get("flag")
    if source == "flags":
        return flag or f.name
    if source:
        return f"{source}: {f.name}"
    return f"{f.name} ({flag})" if flag else f.name


def _shown(value):
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def check_settings(settings, source=None):
    """``settings`` (a dict of :class:`TrainConfig` keys) with every value checked against its
    field's ``check`` and converted to the field's type (a list background becomes a tuple of
    floats, an integral ``densify_stop_rel`` a float). ``source``: how errors name a key: None
    (the library: ``max_vertices (--max-vertices)``), ``"flags"`` (``--max-vertices``) or a
    config file's label (``--config run.toml: max_vertices``). With a ``source`` the file system
    is checked too (``normals`` must be an existing folder).

    Raises:
        ConfigError: an unknown key (a table of a TOML file included), or a value of the wrong
            type or out of range; one line naming the key and what it accepts.
    """
    known = {f.name: f for f in fields(TrainConfig)}
    unknown = sorted(set(settings) - set(known), key=str)
    if unknown:
        k = unknown[0]
        what = "table" if isinstance(settings[k], dict) else "key"
        close = difflib.get_close_matches(str(k), list(known), n=1)
        raise ConfigError(f"{source + ': ' if source and source != 'flags' else ''}unknown {what} {k!r}"
                          f"{f' (and {len(unknown) - 1} more)' if len(unknown) > 1 else ''}; "
                          + (f"did you mean {close[0]!r}? " if close else "") + f"the settings are {', '.join(known)}")
    out = {}
    for name, value in settings.items():
        check = known[name].metadata.get("check")
        try:
            out[name] = value if check is None else check.convert(value, disk=source is not None)
        except ValueError as exc:
            raise ConfigError(f"{_label(known[name], source)}: expected {exc}, got {_shown(value)}") from None
    return out


def preset_defaults(quick):
    """``{field: default}`` of the fields whose default depends on the preset."""
    out = {"quick": bool(quick)}
    for f in fields(TrainConfig):
        if quick and f.metadata.get("quick") is not None:
            out[f.name] = f.metadata["quick"]
        elif f.metadata.get("quick") is not None:
            out[f.name] = f.default
    return out


def cli_options():
    """``(field, flag, help, argparse keywords)`` of every field with a command-line flag, in
    declaration order; ``help`` ends with the default (and the quick preset's, where it differs)."""
    out = []
    for f in fields(TrainConfig):
        meta = f.metadata
        if not meta.get("flag"):
            continue
        shown = ("on" if f.default else "off") if isinstance(f.default, bool) else f.default
        if f.default is None or meta["argparse"].get("action"):
            tail = ""
        elif meta.get("quick") is not None:
            tail = f" (default {shown}, quick: {meta['quick']})"
        else:
            tail = f" (default {shown})"
        out.append((f.name, meta["flag"], meta["help"] + tail, dict(meta["argparse"])))
    return out


def load_config_file(path):
    """The keys of a ``--config`` file (JSON, or TOML by its ``.toml`` suffix), checked
    against :class:`~tsplus_wgpu.train.config.TrainConfig`'s fields (``adapter``, written to
    config.json, is ignored)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"--config {path}: no such file")
    try:
        if path.suffix.lower() == ".toml":
            import tomllib
            data = tomllib.loads(path.read_text())
        else:
            data = json.loads(path.read_text())
    except Exception as exc:
        raise ValueError(f"--config {path}: not valid {'TOML' if path.suffix.lower() == '.toml' else 'JSON'} "
                         f"({exc})") from None
    if not isinstance(data, dict):
        raise ValueError(f"--config {path}: expected a table of settings")
    data.pop("adapter", None)
    return check_settings(data, source=f"--config {path}")     # unknown keys, types and ranges: one line


__all__ = ["TrainConfig", "ConfigError", "MAX_ITERATIONS", "MAX_VERTICES", "MAX_SEED", "check_settings", "option",
           "preset_defaults", "cli_options", "load_config_file"]
