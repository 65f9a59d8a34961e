"""``tsplus bench-backward``: forward + backward per stage (median of repeats, adapter
named), the backward/forward ratio (target <= 2.5) and the backward blend kernel's
fraction of the device's measured peak FMA rate. A command, never a test."""

from __future__ import annotations

import platform
import statistics
import time

import numpy as np

from ..kernels.blend import kernel_layout
from .measure import (BACKWARD_BLEND_FLOPS, backward_blend_flops, backward_blend_work, git_commit, stage_medians,
                      measure_peak_flops, synthetic_scene)


def bench_backward(renderer, m=100_000, width=640, height=480, sigma=0.5, repeats=5, progress=None):
    """Forward and backward per stage on :func:`~.measure.synthetic_scene` (``m`` triangles):
    medians of ``repeats`` after a warm-up, the backward/forward ratio and the backward blend's
    FLOP rate (:data:`~.measure.BACKWARD_BLEND_FLOPS`)."""
    from ..render.backward import backward
    model, cam = synthetic_scene(m, width, height)
    rng = np.random.default_rng(1)
    vi = rng.normal(size=(height, width, 3)).astype(np.float32)
    vt = rng.normal(size=(height, width)).astype(np.float32)
    res = renderer.forward(model, cam, sigma)            # warm-up: pipelines, buffers
    backward(renderer, res, vi, vt)
    fwd_runs, bwd_runs, fwd_wall, bwd_wall = [], [], [], []
    g = None
    for _ in range(repeats):
        renderer.ctx.wait()
        t0 = time.perf_counter()
        res = renderer.forward(model, cam, sigma, profile=True)
        renderer.ctx.wait()
        t1 = time.perf_counter()
        g = backward(renderer, res, vi, vt, profile=True)
        t2 = time.perf_counter()
        fwd_runs.append(res.timings)
        bwd_runs.append(g.timings)
        fwd_wall.append(t1 - t0)
        bwd_wall.append(t2 - t1)
        if progress:
            progress()
    fwd, bwd = stage_medians(fwd_runs), stage_medians(bwd_runs)
    work = backward_blend_work(renderer.ctx, g)
    assert work["evaluations"] == int(res.n_contrib.astype(np.int64).sum())
    flops = backward_blend_flops(work)
    blend_s = bwd.get("rasterize_backward", float("nan")) * 1e-3
    return {
        "triangles": m, "vertices": model.num_vertices, "width": width, "height": height, "sigma": sigma,
        "pairs": res.num_pairs, "repeats": repeats,
        "forward_stage_ms_median": fwd, "backward_stage_ms_median": bwd,
        "forward_gpu_ms": sum(fwd.values()), "backward_gpu_ms": sum(bwd.values()),
        "backward_over_forward": sum(bwd.values()) / sum(fwd.values()),
        "forward_wall_ms_median": 1e3 * statistics.median(fwd_wall),
        "backward_wall_ms_median": 1e3 * statistics.median(bwd_wall),
        "backward_blend_work": work, "backward_blend_flops": flops,
        "backward_blend_flops_per_s": flops / blend_s if blend_s > 0 else float("nan"),
    }


def format_table(result):
    """The result of :func:`backward_report` as text: the stages side by side, ratio, fraction of peak."""
    row = result["row"]
    peak = result["peak"]["flops_per_s"]
    out = [f"adapter: {result['adapter']}   timing: {result['timing']}   kernel layout: {result.get('layout', '?')}",
           f"scene: {row['triangles']:,} triangles, {row['width']}x{row['height']}, sigma {row['sigma']}, "
           f"{row['pairs']:,} tile-triangle pairs; medians of {row['repeats']}",
           f"peak FMA rate: {peak / 1e9:.1f} GFLOP/s", ""]
    out.append(f"{'forward stage':<24}{'ms':>10}      {'backward stage':<24}{'ms':>10}")
    f, b = list(row["forward_stage_ms_median"].items()), list(row["backward_stage_ms_median"].items())
    for i in range(max(len(f), len(b))):
        left = f"{f[i][0]:<24}{f[i][1]:>10.2f}" if i < len(f) else " " * 34
        right = f"{b[i][0]:<24}{b[i][1]:>10.2f}" if i < len(b) else ""
        out.append(f"{left}      {right}")
    out.append(f"{'forward total':<24}{row['forward_gpu_ms']:>10.2f}      {'backward total':<24}{row['backward_gpu_ms']:>10.2f}")
    out.append("")
    out.append(f"backward / forward: {row['backward_over_forward']:.2f} (target <= 2.5)")
    frac = row["backward_blend_flops_per_s"] / peak
    out.append(f"backward blend: {row['backward_blend_flops_per_s'] / 1e9:.2f} GFLOP/s (FLOPs of the algorithm, BACKWARD_BLEND_FLOPS) = "
               f"{100 * frac:.1f} % of peak (target >= 15 %)")
    out.append(f"wall ms (incl. uploads, readback): forward {row['forward_wall_ms_median']:.1f}, "
               f"backward {row['backward_wall_ms_median']:.1f}")
    if "corner_sort" not in row["backward_stage_ms_median"]:
        out.append("corner_sort: not run (the corner order is kept per topology; the warm-up call sorted it)")
    return "\n".join(out)


def backward_report(renderer, m=100_000, width=640, height=480, sigma=0.5, repeats=5, progress=None):
    """The peak FMA rate and :func:`bench_backward`'s row with the adapter and the run's metadata
    (the ``--json`` document of ``tsplus bench-backward``)."""
    ctx = renderer.ctx
    peak = measure_peak_flops(ctx)
    row = bench_backward(renderer, m, width, height, sigma, repeats, progress=progress)
    return {"adapter": ctx.name, "adapter_info": {k: str(v) for k, v in ctx.info.items()}, "layout": kernel_layout(ctx),
            "timing": "timestamp queries" if ctx.features.timestamps else "host (per-stage submits)",
            "host": platform.node(), "date": time.strftime("%Y-%m-%d %H:%M:%S"), "peak": peak, "row": row,
            "backward_blend_flops_model": BACKWARD_BLEND_FLOPS, "commit": git_commit()}


__all__ = ["BACKWARD_BLEND_FLOPS", "bench_backward", "format_table", "backward_report"]
