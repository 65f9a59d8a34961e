"""Held-out views side by side: ground truth | one or more evaluated meshes, one row per scene.

Reads the folders ``tsplus eval`` writes (``metrics.json`` and ``view_NNN.png``, each image
ground truth | render | error heat map) and draws, for every scene, one held-out view: the
ground truth, then each mesh's render titled with its PSNR on that view and its mean over all
held-out views. The view is the one where the last mesh's PSNR is closest to its own mean (a
typical view, not the best), unless given.

    python -m tsplus_wgpu.bench.compare --out docs/bench/real_scenes.png \\
        --row cup "Poisson=runs/poisson-cup" "ours=runs/cup/eval" [--row ...]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from ..apps.evaluate import view_image_name
from .plots import _plt, _save


def load_eval(folder):
    """``(views {view: psnr}, mean psnr, adapter)`` of a ``tsplus eval`` output folder."""
    folder = Path(folder)
    path = folder / "metrics.json"
    try:
        m = json.loads(path.read_text())
        views = {int(v["view"]): float(v["psnr"]) for v in m["views"]}
        return views, float(m["mean_psnr"]), str(m.get("adapter", "?"))
    except FileNotFoundError:
        raise ValueError(f"{path}: not found; run `tsplus eval ... --out {folder}` first") from None
    except (ValueError, KeyError, TypeError) as e:
        raise ValueError(f"{path}: not a `tsplus eval` metrics file ({e})") from None


def panels(folder, view):
    """``(ground truth, render)`` of ``view`` from ``folder/view_NNN.png`` (three equal panels)."""
    import imageio.v3 as iio
    path = Path(folder) / view_image_name(view)
    if not path.is_file():
        raise ValueError(f"{path}: not found; `tsplus eval --write-images N` writes the first N held-out views")
    img = np.asarray(iio.imread(path))[..., :3]
    w = img.shape[1] // 3
    if w == 0 or img.shape[1] != 3 * w:
        raise ValueError(f"{path}: expected ground truth | render | error side by side (width divisible by 3)")
    return img[:, :w], img[:, w:2 * w]


def typical_view(views, mean, written):
    """The view among ``written`` whose PSNR is closest to ``mean`` (ties: the lower index)."""
    cand = sorted(v for v in views if v in written)
    if not cand:
        raise ValueError("no held-out view has an image in every folder")
    return min(cand, key=lambda v: (abs(views[v] - mean), v))


def compare_figure(rows, out, view=None):
    """Write the figure. ``rows``: ``[(scene name, [(label, eval folder), ...]), ...]``; the
    last folder of a row picks its view (:func:`typical_view`) unless ``view`` is given.
    Returns ``[(scene, view, [(label, psnr on the view, mean psnr), ...]), ...]``."""
    if not rows:
        raise ValueError("--row: give at least one scene")
    plt = _plt()
    cols = 1 + max(len(meshes) for _, meshes in rows)
    fig, axes = plt.subplots(len(rows), cols, figsize=(2.6 * cols, 2.2 * len(rows)), squeeze=False)
    summary, adapters = [], set()
    for r, (scene, meshes) in enumerate(rows):
        evals = [(label, folder, *load_eval(folder)) for label, folder in meshes]
        written = {v for v in evals[-1][2] if all((Path(f) / view_image_name(v)).is_file() for _, f, *_ in evals)}
        v = typical_view(evals[-1][2], evals[-1][3], written) if view is None else int(view)
        gt, _ = panels(evals[0][1], v)
        axes[r][0].imshow(gt)
        axes[r][0].set_title(f"{scene}, view {v}: ground truth", fontsize=8)
        got = []
        for c, (label, folder, views, mean, adapter) in enumerate(evals, start=1):
            adapters.add(adapter)
            axes[r][c].imshow(panels(folder, v)[1])
            axes[r][c].set_title(f"{label}: {views.get(v, float('nan')):.1f} dB (mean {mean:.1f})", fontsize=8)
            got.append((label, views.get(v), mean))
        for ax in axes[r]:
            ax.axis("off")
        summary.append((scene, v, got))
    fig.text(0.01, 0.005, f"held-out views, the exported meshes drawn depth-tested | adapter: {', '.join(sorted(adapters))}",
             fontsize=7, color="0.35", ha="left", va="bottom")
    fig.tight_layout(rect=(0, 0.02, 1, 1))
    _save(fig, out)
    plt.close(fig)
    return summary


def _mesh(text):
    label, sep, folder = text.partition("=")
    if not sep or not label or not folder:
        raise argparse.ArgumentTypeError(f"expected LABEL=EVAL_FOLDER, got {text!r}")
    return label, folder


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m tsplus_wgpu.bench.compare",
                                description="Held-out views side by side from `tsplus eval` folders: ground "
                                            "truth | each mesh, one row per scene, titled with PSNR.")
    p.add_argument("--out", required=True, help="PNG to write")
    p.add_argument("--row", nargs="+", action="append", metavar="SCENE LABEL=EVAL", required=True,
                   help="a scene name, then LABEL=FOLDER per mesh (`tsplus eval --out FOLDER`)")
    p.add_argument("--view", type=int, help="this held-out view in every row (default: a typical one per row)")
    args = p.parse_args(argv)
    try:
        rows = []
        for row in args.row:
            if len(row) < 2:
                raise ValueError(f"--row {' '.join(row)}: expected a scene name and at least one LABEL=FOLDER")
            rows.append((row[0], [_mesh(t) for t in row[1:]]))
        for scene, v, got in compare_figure(rows, args.out, args.view):
            print(f"{scene} view {v}: " + ", ".join(f"{lab} {ps:.2f} dB (mean {mean:.2f})" for lab, ps, mean in got))
    except (ValueError, OSError, argparse.ArgumentTypeError) as e:
        raise SystemExit(f"compare: error: {e}") from None
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
