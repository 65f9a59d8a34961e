"""Everything that determines a training run: :class:`TrainConfig`.

Each field is declared once, with its default, its help text and (for the settings
``tsplus train`` exposes) its command-line flag in the field's metadata; ``cli/train.py`` builds
its options from :func:`cli_options`, so the library and the command cannot disagree on a
default. A field whose default differs under ``--preset quick`` names that value as well
(``quick=``); :meth:`TrainConfig.preset` applies it.
"""

from __future__ import annotations

from dataclasses import MISSING, dataclass, field, fields

from .schedules import SIGMA_FINAL, Schedule


def option(default=MISSING, help="", flag=None, quick=None, default_factory=MISSING, **argparse):
    """A :class:`TrainConfig` field: ``default`` (or ``default_factory``), ``help`` (one
    sentence, no default in it: the CLI appends that), ``flag`` (the ``tsplus train`` option,
    None: config files only), ``quick`` (the default under ``--preset quick`` when it differs)
    and further ``argparse`` keywords for the flag (``type``, ``metavar``, ``choices``...)."""
    meta = dict(help=help, flag=flag, quick=quick, argparse=argparse)
    if default_factory is not MISSING:
        return field(default_factory=default_factory, metadata=meta)
    return field(default=default, metadata=meta)


@dataclass
class TrainConfig:
    """Everything that determines a run (written to ``config.json``, stored in checkpoints).
    The help text of every field is in its metadata (``tsplus train --help`` shows it); the
    ablation switches ``hard_prune``, ``weight_prune``, ``sigma_decay``, ``sigma_final`` and
    ``opacity`` are the paper's Tables 2-3 (:class:`~.schedules.Schedule` documents each,
    ``ablations.ABLATIONS`` names the rows)."""

    iterations: int = option(30000, "optimisation steps (the paper: 30000)", flag="--iterations", quick=3000,
                             type=int)
    quick: bool = option(False, "scale every schedule's iteration constants to `iterations` (--preset quick)")
    indoor: bool = option(False, "the indoor constants of method.md", flag="--indoor", action="store_const",
                          const=True)
    seed: int = option(0, "seed of the view order (nothing else is random)", flag="--seed", type=int)
    sh_degree: int = option(3, "SH degree of the model's storage (the schedule raises the trained degree)")
    background: tuple = option((0.0, 0.0, 0.0), "RGB behind the triangles (tsplus train: the scene's)")
    near: float = option(0.01, "near plane (scene units)")
    log_every: int = option(100, "iterations between log lines (host readback only then; 0: none)",
                            flag="--log-every", quick=25, type=int)
    checkpoint_every: int = option(1000, "iterations between checkpoints (0: only at the end or on Ctrl-C)",
                                   flag="--checkpoint-every", type=int)
    opacity_reg: bool = option(True, "apply the early opacity loss of method.md")
    topology: bool = option(
        True, "pruning and densification during training (the final cleanup runs either way). The quick preset "
              "keeps at least 3 epochs between topology events and a 10x opacity learning rate (config keys "
              "quick_topology_epochs, quick_opacity_lr_scale) so that opacities separate before a prune. Measured "
              "on procedural:small, quick, 3000 iterations: held-out mesh PSNR 25.56 dB with topology vs 22.14 dB "
              "without; on runs of a few hundred iterations on a tiny scene it does not pay off (tiny, 600: 20.91 "
              "on vs 21.92 dB off): use off there", flag="--topology", choices=["on", "off"])
    max_vertices: int = option(3_000_000, "densification cap (method.md)", flag="--max-vertices", type=int)
    densify_stop_rel: float = option(
        0.01, "stop densifying when the mean training L1 of the last 3 topology windows improved by less than this "
              "fraction on the 3 before (0: never)", flag="--densify-stop", type=float,
        metavar="DENSIFY_STOP")
    densify_stop_windows: int = option(3, "K of the densification stop: windows in each of the two compared means")
    quick_topology_epochs: float = option(
        3.0, "with quick, at least this many epochs (passes over the training views) between topology events, so "
             "the first prune comes after the opacities have had time to separate and every weight prune sees "
             "every view")
    quick_opacity_lr_scale: float = option(
        10.0, "with quick, the opacity learning rate is multiplied by this (a 300-iteration run has 1/100 of the "
              "paper's steps: at 0.03 a logit moves at most 1.2 before the first scaled prune)")
    hard_prune: bool = option(True, "ablation: False drops the opacity criterion of pruning")
    weight_prune: bool = option(True, "ablation: False drops the blending-weight criterion of pruning")
    sigma_decay: bool = option(True, "ablation: False trains at sigma_final throughout")
    sigma_final: float = option(SIGMA_FINAL, "ablation: final sigma, 0.0001 (hard) or 0.1 (soft)")
    opacity: str = option("opaque", "ablation: 'opaque' (the floor ramps to 0.9999) or 'free' (no floor)")
    normals: str | None = option(
        None, "normal-map priors: add the normal loss 0.05 (indoor 0.025) * mean(1 - <N_rendered, N_prior>) for "
              "iterations > 5000 (scaled with --preset quick) on the training views that have a map (off without "
              "--normals; views without a map get none, the count is printed). One file per view named like its "
              "image with .npy (float [H, W, 3], the normal) or .png (8/16-bit, rgb = (n + 1) / 2, alpha 0 = no "
              "prior); normals in the view's camera space, OpenCV axes (x right, y down, z forward), facing the "
              "camera (z mostly < 0); pixels whose normal is (near) zero, black or masked are ignored; other sizes "
              "are area-resized with a warning. `tsplus inspect procedural:tiny --write-normals DIR` writes the "
              "procedural scene's true maps", flag="--normals", metavar="DIR")
    extra: dict = option(help="free-form notes stored with the run (scene, downscale, ablation...)",
                         default_factory=dict)

    def schedule(self, views=1):
        return Schedule(total=int(self.iterations), indoor=bool(self.indoor), quick=bool(self.quick),
                        views=int(views), topology_epochs=float(self.quick_topology_epochs),
                        opacity_lr_scale=float(self.quick_opacity_lr_scale), hard_prune=bool(self.hard_prune),
                        weight_prune=bool(self.weight_prune), sigma_decay=bool(self.sigma_decay),
                        sigma_final=float(self.sigma_final), opacity_mode=str(self.opacity))

    @classmethod
    def preset(cls, quick=False, **overrides):
        """A config with the defaults of ``--preset quick`` (``quick=True``) or ``paper``, then
        ``overrides``: what ``tsplus train`` builds."""
        return cls(**{**preset_defaults(quick), **overrides})

    #: fields that must match for ``--resume`` (the others may change between sessions)
    RESUME_KEYS = ("iterations", "quick", "indoor", "seed", "sh_degree", "background", "near", "opacity_reg",
                   "topology", "max_vertices", "densify_stop_rel", "densify_stop_windows", "quick_topology_epochs",
                   "quick_opacity_lr_scale", "hard_prune", "weight_prune", "sigma_decay", "sigma_final", "opacity",
                   "normals")


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


__all__ = ["TrainConfig", "option", "preset_defaults", "cli_options"]
