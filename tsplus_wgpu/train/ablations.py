"""The paper's ablations (Triangle Splatting+, Tables 2-3) as named :class:`~.trainer.TrainConfig`
overrides, with the paper's numbers beside them (Mip-NeRF360, full resolution, 30k iterations).

``tsplus train --ablation NAME`` and ``tsplus bench`` use these names. Every row changes only
the keys listed; the baseline is the method as configured otherwise.

What each switch does (see :class:`~.schedules.Schedule`):

* ``hard_prune=False``: no opacity criterion in any prune step. The paper's hard pruning step is
  the opacity test at 5k; method.md (as the authors' code) applies that test at every prune
  step, so only removing the step at 5000 would leave the same test at 4500 and 5500.
* ``weight_prune=False``: pruning by opacity (and size) only.
* ``sigma_decay=False``: sigma is the final value from the first iteration (solid triangles).
* ``sigma_final=0.1``: the paper's "soft" (it "denotes 0.1"); "hard" is 0.0001.
* ``opacity="free"``: no opacity floor, opacity optimised to the end ("free"); "opaque" ramps the
  floor to 0.9999.

The paper measures the soft / free variants as trained (semi-transparent, soft triangles);
the exported mesh drops sigma and opacity, so ``tsplus bench`` reports both.
"""

from __future__ import annotations

#: the paper's baseline (Mip-NeRF360): PSNR, LPIPS, SSIM
PAPER_BASELINE = {"psnr": 25.28, "lpips": 0.289, "ssim": 0.751}

#: name -> (table, label, config overrides, paper's change against the baseline)
ABLATIONS = {
    "baseline": ("2-3", "baseline (hard sigma, opaque)", {}, {"psnr": 0.0, "lpips": 0.0, "ssim": 0.0}),
    "no-hard-prune": ("2", "w/o hard pruning step", {"hard_prune": False},
                      {"psnr": -0.46, "lpips": +0.029, "ssim": -0.025}),
    "no-weight-prune": ("2", "w/o blending weight pruning", {"weight_prune": False},
                        {"psnr": -0.51, "lpips": +0.069, "ssim": -0.045}),
    "no-sigma-decay": ("2", "w/o sigma decay", {"sigma_decay": False},
                       {"psnr": -6.84, "lpips": +0.243, "ssim": -0.282}),
    "soft-opaque": ("3", "soft sigma (0.1), opaque", {"sigma_final": 0.1},
                    {"psnr": +0.31, "lpips": -0.018, "ssim": +0.013}),
    "hard-free": ("3", "hard sigma, free opacity", {"opacity": "free"},
                  {"psnr": +1.26, "lpips": -0.048, "ssim": +0.032}),
    "soft-free": ("3", "soft sigma (0.1), free opacity", {"sigma_final": 0.1, "opacity": "free"},
                  {"psnr": +1.34, "lpips": -0.054, "ssim": +0.038}),
}


def ablation_overrides(name):
    """The TrainConfig keys of ablation ``name`` (a ``ValueError`` naming the choices otherwise)."""
    if name not in ABLATIONS:
        raise ValueError(f"--ablation {name}: unknown; choose one of {', '.join(ABLATIONS)}")
    return dict(ABLATIONS[name][2])


__all__ = ["ABLATIONS", "PAPER_BASELINE", "ablation_overrides"]
