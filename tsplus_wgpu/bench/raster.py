"""``tsplus bench-raster`` (a command, never a test): the forward rasterizer's per-stage cost
for several triangle counts against the device's peak FMA rate. Every timing is a median of
repeats, names the adapter, and stands next to an exactness figure (the image against the
float64 twin, which the caller hands in: production code does not import the twins)."""

from __future__ import annotations

import platform
import statistics
import time

import numpy as np

from ..kernels.blend import kernel_layout
from .measure import BLEND_FLOPS, blend_flops, git_commit, measure_peak_flops, synthetic_scene

def _time_forward(renderer, model, cam, sigma, repeats, progress=None):
    """``repeats`` profiled forward passes after a warm-up: per-run stage times (ms), wall times
    (s) and the last result."""
    renderer.forward(model, cam, sigma).image          # warm-up: pipelines, buffers
    stage_runs, walls = [], []
    last = None
    for _ in range(repeats):
        renderer.ctx.wait()
        t0 = time.perf_counter()
        res = renderer.forward(model, cam, sigma, profile=True)
        res.image
        walls.append(time.perf_counter() - t0)
        stage_runs.append(res.timings)
        last = res
        if progress:
            progress()
    return stage_runs, walls, last


def _twin_error(image, ref):
    """The image against the float64 twin's ``ref`` (a ``reference.render`` result), on the
    pixels the twin does not call ambiguous."""
    ok = ~ref.ambiguous
    err = np.abs(image - ref.image).max(axis=-1)
    return {"max_abs_error_vs_twin": float(err[ok].max()), "share_within_1e-5": float((err[ok] <= 1e-5).mean()),
            "pixels_compared": int(ok.sum())}


def bench_raster(renderer, counts=(10_000, 100_000, 1_000_000), width=640, height=480, sigma=0.5, repeats=5,
                 check_exact_up_to=10_000, progress=None, reference_render=None):
    """One row per triangle count: per-stage medians and min-max, GPU and wall time, triangles/s,
    pixel-triangle evaluations/s and the blend's GFLOP/s. With ``reference_render`` (the float64
    twin's ``render(model, camera, sigma)``) counts up to ``check_exact_up_to`` are compared with it."""
    rows = []
    for m in counts:
        model, cam = synthetic_scene(m, width, height)
        stage_runs, walls, last = _time_forward(renderer, model, cam, sigma, repeats, progress)
        stages = {k: statistics.median(r.get(k, 0.0) for r in stage_runs) for k in stage_runs[0]}
        spread = {k: (min(r.get(k, 0.0) for r in stage_runs), max(r.get(k, 0.0) for r in stage_runs))
                  for k in stage_runs[0]}
        work = last.work
        evals = work["evaluations"]
        flops = blend_flops(work)
        blend_s = stages.get("rasterize_forward", float("nan")) * 1e-3
        gpu_ms = sum(stages.values())
        row = {
            "triangles": m, "width": width, "height": height, "sigma": sigma, "pairs": last.num_pairs,
            "stage_ms_median": stages, "stage_ms_min_max": spread, "gpu_ms_median": gpu_ms,
            "wall_ms_median": 1e3 * statistics.median(walls), "wall_ms_min": 1e3 * min(walls),
            "triangles_per_s": m / (gpu_ms * 1e-3), "blend_work": work,
            "evals_per_s": evals / blend_s if blend_s > 0 else float("nan"),
            "blend_flops": flops,
            "blend_flops_per_s": flops / blend_s if blend_s > 0 else float("nan"),
        }
        if reference_render is not None and m <= check_exact_up_to:
            row.update(_twin_error(last.image, reference_render(model, cam, sigma)))
        rows.append(row)
    return rows


def format_table(result):
    """The result of :func:`raster_report` as a text table (one column per triangle count)."""
    lines = []
    peak = result["peak"]["flops_per_s"]
    lines.append(f"adapter: {result['adapter']}   commit: {result['commit']}   timing: {result['timing']}")
    lines.append(f"kernel layout: {result.get('layout', '?')}")
    lines.append(f"peak FMA rate: {peak / 1e9:.1f} GFLOP/s (median of {len(result['peak']['seconds_all'])})")
    stage_names = []
    for row in result["rows"]:
        for k in row["stage_ms_median"]:
            if k not in stage_names:
                stage_names.append(k)
    head = f"{'stage (ms, median)':<22}" + "".join(f"{r['triangles']:>14,}" for r in result["rows"])
    lines.append(head)
    lines.append("-" * len(head))
    for k in stage_names:
        lines.append(f"{k:<22}" + "".join(f"{r['stage_ms_median'].get(k, 0.0):>14.2f}" for r in result["rows"]))
    def line(label, fn):
        lines.append(f"{label:<22}" + "".join(f"{fn(r):>14}" for r in result["rows"]))
    line("GPU total ms", lambda r: f"{r['gpu_ms_median']:.2f}")
    line("wall ms (incl. upload)", lambda r: f"{r['wall_ms_median']:.2f}")
    line("tile-triangle pairs", lambda r: f"{r['pairs']:,}")
    line("triangles/s", lambda r: f"{r['triangles_per_s'] / 1e6:.2f} M")
    line("pixel-tri evals/s", lambda r: f"{r['evals_per_s'] / 1e6:.1f} M")
    line("blend GFLOP/s", lambda r: f"{r['blend_flops_per_s'] / 1e9:.2f}")
    line("blend / peak", lambda r: f"{100 * r['blend_flops_per_s'] / peak:.1f} %")
    line("max |err| vs twin", lambda r: f"{r['max_abs_error_vs_twin']:.1e}" if "max_abs_error_vs_twin" in r else "-")
    line("pixels |err| <= 1e-5", lambda r: f"{100 * r['share_within_1e-5']:.2f} %" if "share_within_1e-5" in r else "-")
    return "\n".join(lines)


def raster_report(renderer, counts, width=640, height=480, sigma=0.5, repeats=5, reference_render=None,
                  progress=None, log=print):
    """The peak FMA rate and :func:`bench_raster`'s rows with the adapter and the run's metadata
    (the ``--json`` document of ``tsplus bench-raster``)."""
    ctx = renderer.ctx
    log(f"adapter: {ctx.name}")
    peak = measure_peak_flops(ctx)
    log(f"peak FMA rate: {peak['flops_per_s'] / 1e9:.1f} GFLOP/s")
    rows = bench_raster(renderer, counts, width, height, sigma, repeats, reference_render=reference_render,
                        progress=progress)
    return {
        "adapter": ctx.name, "adapter_info": {k: str(v) for k, v in ctx.info.items()},
        "layout": kernel_layout(ctx),
        "timing": "timestamp queries" if ctx.features.timestamps else "host (per-stage submits)",
        "commit": git_commit(), "host": platform.node(), "python": platform.python_version(),
        "date": time.strftime("%Y-%m-%d %H:%M:%S"), "peak": peak, "rows": rows,
        "blend_flops_model": BLEND_FLOPS,
    }


__all__ = ["bench_raster", "format_table", "raster_report", "synthetic_scene"]
