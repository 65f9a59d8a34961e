"""The ``tsplus bench`` report: the per-scene tables (stages, ablations, budgets, headline)
built from the runs' records, ``report.md`` rendered from ``report.json``, and both written
atomically with the plots."""

from __future__ import annotations

import json
import math
import statistics
from pathlib import Path

import numpy as np

from ..io.atomic import write_text
from .measure import stats

REPORT_VERSION = 1


def json_safe(obj):
    """JSON-safe: numpy scalars to Python, non-finite floats to None."""
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.floating, float)):
        f = float(obj)
        return f if math.isfinite(f) else None
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


def one_line(exc):
    """An exception as one short line (for a report's error field)."""
    text = f"{type(exc).__name__}: {exc}".strip().splitlines()
    return text[0][:300] if text else type(exc).__name__


# ---------------------------------------------------------------------------------------- summaries

def summarize_stages(rows, iterations, method):
    """Median and min-max per stage over the profiled steps that edited nothing; the topology
    edits separately, amortised over the run."""
    from ..train.profile import STAGES
    plain = [r for r in rows if not r["topology_step"]] or rows
    keys = list(STAGES) + ["other", "wall"]
    out = dict(method=method, profiled=len(rows), plain_steps=len(plain),
               ms={k: stats([r[k] for r in plain]) for k in keys})
    edits = [r for r in rows if r["topology_step"]]
    acc = out["ms"]["topology"]["median"] if out["ms"]["topology"] else 0.0
    edit_ms = [max(0.0, r["topology"] - acc) for r in edits]
    out["topology_edits"] = dict(count=len(edits), ms=stats(edit_ms),
                                 amortised_ms_per_iteration=sum(edit_ms) / max(1, iterations))
    gpu = statistics.median(sum(r[k] for k in STAGES) for r in plain)
    out["timestamps_plausible"] = bool(gpu >= 0.1 * statistics.median(r["wall"] for r in plain))
    return out


def ablation_table(runs, names, ablations, paper_baseline):
    """One row per ablation: its final numbers, the change against the baseline run and the paper's."""
    base = runs.get("ablation-baseline")
    rows = []
    for name in names:
        r = runs.get(f"ablation-{name}")
        table, label, over, paper = ablations[name]
        row = dict(name=name, table=table, label=label, overrides=over, paper_delta=paper,
                   paper_psnr=paper_baseline["psnr"] + paper["psnr"], paper_ssim=paper_baseline["ssim"] + paper["ssim"])
        if r is None or "error" in r:
            row["error"] = (r or {}).get("error", "not run")
            rows.append(row)
            continue
        f = r["final"]
        row.update(mesh_psnr=f["mesh_psnr"], mesh_ssim=f["mesh_ssim"], soft_psnr=f["soft_psnr"], soft_ssim=f["soft_ssim"],
                   mesh_vertices=f["mesh_vertices"], mesh_triangles=f["mesh_triangles"],
                   model_vertices=f["model_vertices"], train_seconds=r["train_seconds"], its_per_s=r["its_per_s"])
        if base is not None and "error" not in base:
            b = base["final"]
            row.update(delta_mesh_psnr=f["mesh_psnr"] - b["mesh_psnr"], delta_soft_psnr=f["soft_psnr"] - b["soft_psnr"],
                       delta_mesh_ssim=f["mesh_ssim"] - b["mesh_ssim"], delta_soft_ssim=f["soft_ssim"] - b["soft_ssim"],
                       vertices_ratio=f["mesh_vertices"] / max(1, b["mesh_vertices"]),
                       time_ratio=r["train_seconds"] / max(1e-9, base["train_seconds"]))
        rows.append(row)
    return rows


def budget_table(runs):
    """Vertices vs PSNR: the plateau stop, the no-stop run and the budget runs, one row each."""
    rows = []
    for key, label in [("ablation-baseline", "plateau stop (densify_stop_rel 0.01)"),
                       ("densify-no-stop", "no stop (densify_stop_rel 0)")] + \
            sorted(((k, None) for k in runs if k.startswith("budget-")), key=lambda kv: float(kv[0].split("-", 1)[1])):
        r = runs.get(key)
        if r is None or "error" in r:
            continue
        f = r["final"]
        cfg = r["config"]
        rows.append(dict(run=key, label=label or f"--max-vertices {cfg['max_vertices']}",
                         max_vertices=cfg["max_vertices"], densify_stop_rel=cfg["densify_stop_rel"],
                         peak_vertices=r["peak_vertices"], model_vertices=f["model_vertices"],
                         mesh_vertices=f["mesh_vertices"], mesh_triangles=f["mesh_triangles"],
                         mesh_psnr=f["mesh_psnr"], mesh_ssim=f["mesh_ssim"], soft_psnr=f["soft_psnr"],
                         densify_stopped=r.get("densify_stopped"), train_seconds=r["train_seconds"]))
    return rows


def headline_rows(report):
    """The headline table's rows: per scene the quick, longer and method runs and the Poisson baseline."""
    rows = []
    for s in report["scenes"]:
        if s.get("status") != "ok":
            rows.append(dict(scene=s["name"], status=s.get("status")))
            continue
        res = f"{s['resolution'][0]}x{s['resolution'][1]}"
        q = s["runs"].get("quick") or {}
        for key, label in (("quick", "quick, topology off"), ("long", "longer, topology off"),
                           ("ablation-baseline", "quick, topology on")):
            r = s["runs"].get(key)
            if r is None or "error" in r:
                continue
            f = r["final"]
            rows.append(dict(scene=s["name"], resolution=res, run=label, iterations=r["iterations"],
                             train_seconds=r["train_seconds"], its_per_s=r["its_per_s"],
                             time_vs_quick=r["train_seconds"] / q["train_seconds"] if q.get("train_seconds") else None,
                             mesh_psnr=f["mesh_psnr"], coverage=f.get("mesh_coverage"),
                             mesh_ssim=f["mesh_ssim"], soft_psnr=f["soft_psnr"], mesh_vertices=f["mesh_vertices"],
                             mesh_triangles=f["mesh_triangles"]))
        p = s.get("poisson")
        if p and "error" not in p:
            rows.append(dict(scene=s["name"], resolution=res, run=f"Poisson (depth {p['depth']})", iterations=None,
                             train_seconds=p["seconds"], its_per_s=None, time_vs_quick=None, mesh_psnr=p["psnr"],
                             coverage=p.get("coverage"),
                             mesh_ssim=p["ssim"],
                             soft_psnr=None, mesh_vertices=p["vertices"], mesh_triangles=p["triangles"]))
    return rows


# ---------------------------------------------------------------------------------------- markdown

def _f(x, fmt="{:.2f}", none="-"):
    return none if x is None else fmt.format(x)


def headline_markdown(report):
    """The headline table in markdown."""
    lines = ["| scene | resolution | run | iterations | train s | x quick | it/s | mesh PSNR | mesh SSIM | coverage "
             "| soft PSNR | vertices | triangles |", "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in headline_rows(report):
        if "status" in r:
            lines.append(f"| {r['scene']} | {r['status']} | | | | | | | | | | | |")
            continue
        lines.append(f"| {r['scene']} | {r['resolution']} | {r['run']} | {_f(r['iterations'], '{:d}')} | "
                     f"{_f(r['train_seconds'], '{:.0f}')} | {_f(r['time_vs_quick'])} | {_f(r['its_per_s'])} | "
                     f"**{_f(r['mesh_psnr'])}** | "
                     f"{_f(r['mesh_ssim'], '{:.3f}')} | {_f(r.get('coverage'), '{:.1%}')} | {_f(r['soft_psnr'])} | "
                     f"{r['mesh_vertices']:,} | "
                     f"{r['mesh_triangles']:,} |")
    return "\n".join(lines)


def _stop_reason(reason):
    """The log's densify_stop reason, short."""
    if not reason:
        return "did not stop"
    if "relative improvement" in reason:
        head, _, tail = reason.partition("mean over the last ")
        return "training L1: last " + tail
    return reason


def _caption(report, s, iterations, runs=()):
    m = report["meta"]
    commits = sorted({s["runs"][k]["commit"] for k in runs if s["runs"].get(k, {}).get("commit")}) or [m["commit"]]
    return (f"adapter {m['adapter']}, kernel layout {m.get('layout', '?')}, {s['resolution'][0]}x{s['resolution'][1]}, "
            f"{iterations} iterations, commit {'+'.join(commits)}")


def _md_header(report):
    """The report's head: adapter, command, wall time, load, the peak FMA rate, the notes."""
    m = report["meta"]
    peak = report.get("peak") or {}
    L = ["# tsplus bench report", "",
         f"- adapter: **{m['adapter']}** ({m['timing']}); kernel layout: {m.get('layout', '?')}; commit "
         f"`{m['commit']}`; {m['date']}; host {m['host']}, {m['cpus']} CPUs",
         f"- command: `{m['command']}`",
         f"- wall time of this invocation: {m['seconds'] / 60:.1f} min" + (" (some runs from the cache)" if m.get("cached_runs") else ""),
         f"- CPU load average (1 min) at start / end: {m['loadavg_start'][0]:.2f} / {m.get('loadavg_end', [float('nan')])[0]:.2f}"
         f" on {m['cpus']} CPUs" + (" — the device is a CPU driver shared with other processes: timings are contended"
                                    if m.get("is_cpu") else ""),
         ]
    commits = sorted({r.get("commit") for s in report["scenes"] for r in s.get("runs", {}).values()
                      if r.get("commit")} - {m["commit"]})
    if commits:
        L.append(f"- some runs come from the cache of an earlier invocation at commit(s) {', '.join(commits)} "
                 f"(each run's commit is in report.json)")
    if peak:
        L.append(f"- peak FMA rate measured in this run: **{peak['median'] / 1e9:.1f} GFLOP/s** (median of "
                 f"{peak['n']} measurements, {peak['min'] / 1e9:.1f}-{peak['max'] / 1e9:.1f})")
    L += ["", "PSNR/SSIM: held-out views; **mesh** = the exported opaque mesh (sigma and opacity dropped, SH DC "
              "colours) drawn by the depth-tested mesh renderer at 4x4 supersampling; **soft** = the model as trained "
              "(its final sigma and opacities) through the splatting renderer at 4x. Train s: training wall time "
              "without evaluations; it/s: of the unprofiled steps. Timings: median [min-max] of repeats.", "",
          "## Headline", "", headline_markdown(report), ""]
    return L


def _md_scene_line(s):
    """The scene's one-line description: folder, resolution, views, time, load."""
    return [f"`{s['scene']}` downscale {s['downscale']}: {s['resolution'][0]}x{s['resolution'][1]}, "
            f"{s['train_views']} training views, evaluated on {s['eval_note']}; {s['points']:,} initial points; "
            f"{s['seconds'] / 60:.1f} min in this invocation"
            + (f" (the runs took {s['measured_seconds'] / 60:.1f} min when measured)" if s.get("measured_seconds")
               and s["measured_seconds"] > 1.2 * s["seconds"] else "")
            + f"; load average {s['loadavg_start'][0]:.2f} -> {s['loadavg_end'][0]:.2f}.", ""]


def _md_curves(report, s):
    """The quick and long runs' evaluation points, one table each."""
    L = []
    for key in ("quick", "long"):
        r = s["runs"].get(key)
        if r is None:
            continue
        if "error" in r:
            L += [f"{key}: failed: {r['error']}", ""]
            continue
        seg = r.get("its_per_s_segments")
        L += [f"**{key}** ({_caption(report, s, r['iterations'], [key])}; {r['train_seconds']:.0f} s, "
              f"{r['its_per_s']:.2f} it/s" + (f" [{seg['min']:.2f}-{seg['max']:.2f} over {seg['n']} segments]"
                                               if seg else "") + "):", "",
              "| iteration | train s | sigma | mesh PSNR | mesh SSIM | soft PSNR | soft SSIM | mesh vertices | "
              "model triangles |", "|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
        for p in r["points"]:
            L.append(f"| {p['iteration']} | {p['train_seconds']:.0f} | {p['sigma']:.4f} | {p['mesh_psnr']:.2f} | "
                     f"{p['mesh_ssim']:.3f} | {p['soft_psnr']:.2f} | {p['soft_ssim']:.3f} | {p['mesh_vertices']:,} | "
                     f"{p['model_triangles']:,} |")
        L.append("")
    return L


def _md_stages(report, s):
    """Per-stage time per iteration of the method's run, and its topology edits."""
    runs = s["runs"]
    b = (runs.get("ablation-baseline") or {}).get("stages")
    if not b:
        return []
    ms = b["ms"]
    L = [f"**Per-stage time per iteration** (method run, topology on; {b['method']}; {b['plain_steps']} profiled "
         f"steps without topology edits; "
         f"{_caption(report, s, runs['ablation-baseline']['iterations'], ['ablation-baseline'])}):", "",
         "| stage | ms median | min-max | share of wall |", "|---|---:|---:|---:|"]
    wall = ms["wall"]["median"] if ms.get("wall") else None
    for k, v in ms.items():
        if v is None:
            continue
        share = f"{100 * v['median'] / wall:.1f} %" if wall and k != "wall" else ""
        L.append(f"| {k} | {v['median']:.2f} | {v['min']:.2f}-{v['max']:.2f} | {share} |")
    if not b.get("timestamps_plausible", True):
        L += ["", "**Warning:** the stages account for less than a tenth of the step's wall time: the "
                  "device's timestamps are not plausible here."]
    te = b["topology_edits"]
    L += ["", f"Topology edits (host round trip: prune, densify, buffers re-created): {te['count']}"
              + (f", {te['ms']['median']:.1f} ms median [{te['ms']['min']:.1f}-{te['ms']['max']:.1f}]"
                 if te["ms"] else "") + f", amortised {te['amortised_ms_per_iteration']:.2f} ms per iteration.", ""]
    return L


def _md_blend(s):
    """The blend kernels against the device's peak FMA rate."""
    bl = (s["runs"].get("quick") or {}).get("blend")
    if not bl:
        return []
    L = [f"**Blend kernels vs the device's peak** (trained quick model, view {bl['view']}, {bl['width']}x"
         f"{bl['height']}, sigma {bl['sigma']:.4g}, {bl['triangles']:,} triangles, {bl['pairs']:,} tile pairs; "
         f"peak {bl['peak']['flops_per_s'] / 1e9:.1f} GFLOP/s measured just before, "
         f"[{bl['peak']['flops_per_s_min'] / 1e9:.1f}-{bl['peak']['flops_per_s_max'] / 1e9:.1f}]):", "",
         "| kernel | ms median [min-max] | GFLOP/s | fraction of peak [range] |", "|---|---:|---:|---:|"]
    for k in ("forward", "backward"):
        x = bl[k]
        if x["ms"] is None:
            continue
        L.append(f"| {x['kernel']} | {x['ms']['median']:.2f} [{x['ms']['min']:.2f}-{x['ms']['max']:.2f}] | "
                 f"{_f(x['gflops_per_s'])} | {_f(x['fraction_of_peak'], '{:.1%}')} "
                 f"[{_f(x['fraction_min'], '{:.1%}')}-{_f(x['fraction_max'], '{:.1%}')}] |")
    if not bl.get("timestamps_plausible", True):
        L.append("\n**Warning:** the forward's timestamps sum to less than a tenth of its wall time: not "
                 "plausible on this device.")
    L.append("")
    return L


def _md_budgets(s):
    """Vertices vs PSNR: the plateau stop, no stop, the budgets and the Poisson baseline."""
    if not s.get("budgets"):
        return []
    L = [f"**Vertices vs PSNR** (topology on, {s['runs'].get('ablation-baseline', {}).get('iterations', '')} "
         f"iterations; --max-vertices budgets V0 + f (peak - V0) with V0 the initial and peak the no-stop "
         f"run's largest vertex count, plateau stop off):", "",
         "| run | max vertices | peak vertices | mesh vertices | mesh PSNR | mesh SSIM | soft PSNR | why "
         "densifying stopped |", "|---|---:|---:|---:|---:|---:|---:|---|"]
    for r in s["budgets"]:
        L.append(f"| {r['label']} | {r['max_vertices']:,} | {r['peak_vertices']:,} | {r['mesh_vertices']:,} | "
                 f"{r['mesh_psnr']:.2f} | {r['mesh_ssim']:.3f} | {r['soft_psnr']:.2f} | "
                 f"{_stop_reason(r['densify_stopped'])}"
                 + (" (capped by the budget)" if not r["densify_stopped"] and r["max_vertices"] < 3_000_000
                    and r["peak_vertices"] >= 0.95 * r["max_vertices"] else "") + " |")
    p = s.get("poisson")
    if p and "error" not in p:
        L.append(f"| Poisson baseline (depth {p['depth']}) | | | {p['vertices']:,} | {p['psnr']:.2f} | "
                 f"{p['ssim']:.3f} | | |")
    L.append("")
    return L


def _md_ablations(report, s):
    """The ablations beside the paper's change."""
    if not s.get("ablations"):
        return []
    runs = s["runs"]
    base = runs.get("ablation-baseline") or {}
    L = [f"**Ablations** ({_caption(report, s, base.get('iterations', '?'), [k for k in runs if k.startswith('ablation-')])}; topology on; change against this "
         f"run's baseline beside the paper's change on Mip-NeRF360, Tables 2-3):", "",
         "| table | ablation | mesh PSNR | Δ mesh | soft PSNR | Δ soft | paper Δ PSNR | mesh SSIM | Δ mesh SSIM "
         "| paper Δ SSIM | vertices (x baseline) | time (x baseline) |",
         "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in s["ablations"]:
        if "error" in r:
            L.append(f"| {r['table']} | {r['label']} | {r['error']} | | | | {r['paper_delta']['psnr']:+.2f} | | | "
                     f"{r['paper_delta']['ssim']:+.3f} | | |")
            continue
        L.append(f"| {r['table']} | {r['label']} | {r['mesh_psnr']:.2f} | {_f(r.get('delta_mesh_psnr'), '{:+.2f}')} | "
                 f"{r['soft_psnr']:.2f} | {_f(r.get('delta_soft_psnr'), '{:+.2f}')} | "
                 f"{r['paper_delta']['psnr']:+.2f} | {r['mesh_ssim']:.3f} | "
                 f"{_f(r.get('delta_mesh_ssim'), '{:+.3f}')} | {r['paper_delta']['ssim']:+.3f} | "
                 f"{r['mesh_vertices']:,} ({_f(r.get('vertices_ratio'))}) | {_f(r.get('time_ratio'))} |")
    L += ["", "The paper reports the soft / free variants as trained (semi-transparent, soft triangles): "
              "compare its change with the *soft* column; the *mesh* column is what survives export.", ""]
    return L


def render_markdown(report):
    """``report.md`` from the report's data (``report.json``)."""
    L = _md_header(report)
    for s in report["scenes"]:
        L += [f"## {s['name']}", ""]
        if s.get("status") != "ok":
            L += [f"{s['scene']}: {s.get('status')}", ""]
            continue
        L += _md_scene_line(s) + _md_curves(report, s)
        for plot in s.get("plots", []):
            L += [f"![{Path(plot).stem}]({plot})", ""]
        L += _md_stages(report, s) + _md_blend(s) + _md_budgets(s) + _md_ablations(report, s)
        p = s.get("poisson")
        if p and "error" in p:
            L += [f"Poisson baseline: failed ({p['error']})", ""]
    return "\n".join(L) + "\n"


# ---------------------------------------------------------------------------------------- files

def peak_summary(peaks):
    """Median, min-max and count of the peak FMA samples (:func:`~.measure.peak_record`)."""
    if not peaks:
        return None
    v = [p["flops_per_s"] for p in peaks]
    return dict(median=statistics.median(v), min=min(v), max=max(v), n=len(v), samples=peaks)


def write_report(report, out, plots=True):
    """report.json, report.md and the plots, each written atomically."""
    out = Path(out)
    report["peak"] = peak_summary(report["meta"].get("_peaks", []))
    if plots:
        from .plots import make_plots
        for s in report["scenes"]:
            if s.get("status") == "ok":
                try:
                    s["plots"] = make_plots(report, s, out)
                except Exception as exc:       # a plot must not lose the measurements
                    s["plots"] = []
                    s["plot_error"] = one_line(exc)
    meta = dict(report["meta"])
    meta.pop("_peaks", None)
    data = json_safe(dict(report, meta=meta))
    write_text(out / "report.json", json.dumps(data, indent=1) + "\n")
    write_text(out / "report.md", render_markdown(data))
    return data


def rewrite_report(out, plots=True):
    """Measure nothing: rewrite ``OUT/report.md`` (and the plots) from ``OUT/report.json``, its
    numbers and metadata kept."""
    out = Path(out)
    report = json.loads((out / "report.json").read_text())
    report["meta"]["_peaks"] = (report.get("peak") or {}).get("samples", [])
    return write_report(report, out, plots=plots)


__all__ = ["REPORT_VERSION", "json_safe", "one_line", "summarize_stages", "ablation_table", "budget_table",
           "headline_rows", "headline_markdown", "render_markdown", "peak_summary", "write_report", "rewrite_report"]
