"""The PNG plots of ``tsplus bench`` (matplotlib, Agg). Every figure names the adapter, the
resolution, the iteration count and the commit; each is written atomically."""

from __future__ import annotations

from pathlib import Path

from ..io.atomic import atomic_path


def _plt():
    import matplotlib
    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt
    return plt


def _save(fig, path):
    path = Path(path)
    with atomic_path(path, keep_suffix=True) as tmp:
        fig.savefig(tmp, dpi=110, bbox_inches="tight")
        from PIL import Image          # 256-colour palette: a third of the size, same look for line plots
        with Image.open(tmp) as im:
            im.convert("RGB").quantize(colors=256, method=Image.Quantize.MEDIANCUT).save(tmp, optimize=True)
    return path.name


def _footer(fig, report, scene, iterations, runs=None):
    m = report["meta"]
    w, h = scene["resolution"]
    # the commit(s) the figure's runs were measured at (cached runs may come from an earlier one)
    rs = [scene["runs"][k] for k in (runs or scene["runs"]) if k in scene["runs"]]
    commit = "+".join(sorted({r["commit"] for r in rs if r.get("commit")})) or m["commit"]
    fig.text(0.01, 0.005, f"adapter: {m['adapter']} | {w}x{h} | {iterations} | commit {commit} | {m['date']}",
             fontsize=7, color="0.35", ha="left", va="bottom")


def _finish(plt, fig, report, scene, iterations, runs, out, kind, bottom=0.03):
    """Footer (adapter, resolution, iterations, commit), layout, atomic save, close; returns
    the file name of ``OUT/<scene>_<kind>.png``."""
    _footer(fig, report, scene, iterations, runs)
    fig.tight_layout(rect=(0, bottom, 1, 1))
    name = _save(fig, Path(out) / f"{scene['name']}_{kind}.png")
    plt.close(fig)
    return name


def plot_curves(report, s, out):
    plt = _plt()
    runs = [(k, s["runs"][k]) for k in ("quick", "long") if k in s["runs"] and "error" not in s["runs"][k]]
    if not runs:
        return None
    fig, axes = plt.subplots(2, 2, figsize=(10, 7))
    colors = {"quick": "tab:blue", "long": "tab:orange"}
    for key, r in runs:
        pts = r["points"]
        x_t = [p["train_seconds"] for p in pts]
        x_i = [p["iteration"] for p in pts]
        for row, metric in enumerate(("psnr", "ssim")):
            for col, x in enumerate((x_t, x_i)):
                ax = axes[row][col]
                ax.plot(x, [p[f"mesh_{metric}"] for p in pts], "o-", color=colors[key],
                        label=f"{key} ({r['iterations']} it): exported opaque mesh")
                ax.plot(x, [p[f"soft_{metric}"] for p in pts], "s--", color=colors[key], alpha=0.55,
                        label=f"{key}: soft model as trained")
    p = s.get("poisson")
    for row, metric in enumerate(("psnr", "ssim")):
        for col, xl in enumerate(("training wall time (s)", "iteration")):
            ax = axes[row][col]
            if p and "error" not in p:
                ax.axhline(p[metric], color="0.4", ls=":", label=f"Poisson baseline ({p['vertices']:,} vertices)")
            ax.set_xlabel(xl)
            ax.set_ylabel(f"held-out {metric.upper()}" + (" (dB)" if metric == "psnr" else ""))
            ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7, loc="lower right")
    its = " / ".join(str(r["iterations"]) for _, r in runs)
    fig.suptitle(f"{s['name']}: held-out PSNR and SSIM vs time and iteration (quick preset, topology off)", fontsize=11)
    return _finish(plt, fig, report, s, f"{its} iterations", [k for k, _ in runs], out, "curves", bottom=0.02)


def plot_stages(report, s, out):
    plt = _plt()
    base = s["runs"].get("ablation-baseline") or {}
    st = base.get("stages")
    if not st:
        return None
    from ..train.profile import STAGES
    names = [k for k in list(STAGES) + ["other"] if st["ms"].get(k)]
    med = [st["ms"][k]["median"] for k in names]
    lo = [st["ms"][k]["median"] - st["ms"][k]["min"] for k in names]
    hi = [st["ms"][k]["max"] - st["ms"][k]["median"] for k in names]
    fig, ax = plt.subplots(figsize=(8, 4.5))
    y = list(range(len(names)))[::-1]
    ax.barh(y, med, xerr=[lo, hi], color="tab:green", alpha=0.8, capsize=3)
    ax.set_yticks(y)
    ax.set_yticklabels(names)
    ax.set_xlabel("ms per iteration (median, bars: min-max)")
    wall = st["ms"]["wall"]["median"] if st["ms"].get("wall") else 0
    bl = (s["runs"].get("quick") or {}).get("blend")
    extra = ""
    if bl and bl["forward"].get("fraction_of_peak") is not None:
        extra = (f"\nblend kernels: forward {100 * bl['forward']['fraction_of_peak']:.1f} %, backward "
                 f"{100 * (bl['backward'].get('fraction_of_peak') or 0):.1f} % of the measured peak "
                 f"{bl['peak']['flops_per_s'] / 1e9:.1f} GFLOP/s")
    ax.set_title(f"{s['name']}: per-stage time of a training step ({st['method']}); wall {wall:.1f} ms{extra}",
                 fontsize=9)
    ax.grid(axis="x", alpha=0.3)
    return _finish(plt, fig, report, s, f"{base['iterations']} iterations", ["ablation-baseline", "quick"], out,
                   "stages")


def plot_vertices(report, s, out):
    plt = _plt()
    rows = s.get("budgets") or []
    if not rows:
        return None
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for r in rows:
        marker = "*" if r["run"] == "ablation-baseline" else ("D" if r["run"] == "densify-no-stop" else "o")
        ax.plot(r["mesh_vertices"], r["mesh_psnr"], marker, ms=9, label=f"{r['label']}")
    q = s["runs"].get("quick")
    if q and "error" not in q:
        ax.plot(q["final"]["mesh_vertices"], q["final"]["mesh_psnr"], "^", ms=8, color="0.3",
                label="quick preset, topology off")
    p = s.get("poisson")
    if p and "error" not in p:
        ax.plot(p["vertices"], p["psnr"], "x", ms=9, color="k", label="Poisson baseline")
    ax.set_xscale("log")
    ax.set_xlabel("vertices of the exported mesh")
    ax.set_ylabel("held-out mesh PSNR (dB)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    n = (s["runs"].get("ablation-baseline") or {}).get("iterations", "?")
    ax.set_title(f"{s['name']}: what the scene needs — vertices vs PSNR (topology on)", fontsize=10)
    return _finish(plt, fig, report, s, f"{n} iterations",
                   ["ablation-baseline", "densify-no-stop", "quick"] + [k for k in s["runs"] if k.startswith("budget-")],
                   out, "vertices")


def plot_ablations(report, s, out):
    plt = _plt()
    rows = [r for r in s.get("ablations") or [] if "error" not in r and r["name"] != "baseline"]
    if not rows:
        return None
    import numpy as np
    fig, ax = plt.subplots(figsize=(9, 4.5))
    x = np.arange(len(rows))
    w = 0.27
    ax.bar(x - w, [r.get("delta_mesh_psnr", 0.0) for r in rows], w, label="here: exported mesh", color="tab:blue")
    ax.bar(x, [r.get("delta_soft_psnr", 0.0) for r in rows], w, label="here: soft model as trained", color="tab:cyan")
    ax.bar(x + w, [r["paper_delta"]["psnr"] for r in rows], w, label="paper (Mip-NeRF360)", color="0.6")
    ax.axhline(0, color="k", lw=0.8)
    ax.set_xticks(x)
    import textwrap
    ax.set_xticklabels([textwrap.fill(r["label"], 16) for r in rows], fontsize=7)
    ax.set_ylabel("PSNR change vs baseline (dB)")
    ax.legend(fontsize=8)
    ax.grid(axis="y", alpha=0.3)
    n = (s["runs"].get("ablation-baseline") or {}).get("iterations", "?")
    ax.set_title(f"{s['name']}: the paper's ablations (Tables 2-3) measured here", fontsize=10)
    return _finish(plt, fig, report, s, f"{n} iterations", [k for k in s["runs"] if k.startswith("ablation-")], out,
                   "ablations")


def make_plots(report, s, out):
    """The plots of one scene record; returns their file names (relative to ``out``)."""
    names = []
    for fn in (plot_curves, plot_stages, plot_vertices, plot_ablations):
        name = fn(report, s, out)
        if name:
            names.append(name)
    return names


__all__ = ["make_plots", "plot_curves", "plot_stages", "plot_vertices", "plot_ablations"]
