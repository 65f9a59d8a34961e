"""``tsplus bench-backward``: forward + backward per stage (median of repeats, adapter
named), the backward/forward ratio (target <= 2.5) and the backward blend kernel's
fraction of the device's measured peak FMA rate. A command, never a test."""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np

#: The backward blend's arithmetic, counted per pixel-pair from the algorithm (not from
#: the compiled code), a transcendental or division counted as one operation:
#:   every evaluation (pair up to the pixel's last contribution): d = p - s (2), three edge
#:   values 1 + g.d (3 x 4), two min (2);
#:   evaluations with ratio >= tau: log2, times sigma, exp2, times opacity, cap (5);
#:   contributions: colour c + cx dx + cy dy (3 x 4), c.v (5), w = alpha T (1), acc += (2),
#:   dL/d alpha = T c.v - (Z - acc) / (1 - alpha) (5), dL/d o = dL/d alpha I (1),
#:   dL/d ratio = dL/d alpha o sigma I / ratio (4), argmin edge (2), T (1 - alpha) (2),
#:   w v (3), and the 19 statistics' sums: 9 colour (w v_c x 1, dx, dy: 1 + 2 + 2 each: 15),
#:   the argmin edge's 3 (5), dL/d o (1).
#: The kernel counts the three kinds of work (its ``work`` buffer).
BACKWARD_BLEND_FLOPS = {"evaluations": 16, "powered": 5, "contributions": 58}


def _peak(ctx):
    try:
        from .bench import measure_peak_flops
    except ImportError:  # pragma: no cover - bench.py absent
        measure_peak_flops = None
    if measure_peak_flops is not None:
        return measure_peak_flops(ctx)
    from .gpu import host_time
    from .stages import PeakFma
    stage = PeakFma(ctx)
    sink = ctx.buffer(16 * 256, "peak_sink")
    groups, iters = 1024, 4096

    def run():
        enc = ctx.device.create_command_encoder()
        stage.dispatch(enc, groups, dict(pp=stage.uniform("PeakParams", iterations=iters), sink=sink))
        ctx.queue.submit([enc.finish()])
    times = [host_time(ctx, run) for _ in range(5)]
    med = statistics.median(times)
    return {"flops_per_s": groups * 256 * iters * 64 / med, "seconds_median": med, "seconds_all": times}


def _scene(m, width, height, seed=0):
    try:
        from .bench import synthetic_scene
        return synthetic_scene(m, width, height, seed=seed)
    except ImportError:  # pragma: no cover
        raise SystemExit("tsplus_wgpu.bench.synthetic_scene is needed for the benchmark scene")


def bench_backward(renderer, m=100_000, width=640, height=480, sigma=0.5, repeats=5, progress=None):
    from .backward import backward
    model, cam = _scene(m, width, height)
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
    med = lambda runs: {k: statistics.median(r.get(k, 0.0) for r in runs) for k in runs[0]}
    fwd, bwd = med(fwd_runs), med(bwd_runs)
    w = renderer.ctx.read(g.buffers["work"], np.uint32, 3)
    work = {"evaluations": int(w[0]), "powered": int(w[1]), "contributions": int(w[2])}
    assert work["evaluations"] == int(res.n_contrib.astype(np.int64).sum())
    flops = sum(BACKWARD_BLEND_FLOPS[k] * work[k] for k in BACKWARD_BLEND_FLOPS)
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
    row = result["row"]
    peak = result["peak"]["flops_per_s"]
    out = [f"adapter: {result['adapter']}   timing: {result['timing']}",
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


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="tsplus bench-backward", description=__doc__)
    ap.add_argument("--adapter", default=None, help="adapter name (e.g. lavapipe); default: best")
    ap.add_argument("--triangles", type=int, default=100_000)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--sigma", type=float, default=0.5)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--json", default=None, help="write the result here")
    args = ap.parse_args(argv)
    from .renderer import Renderer
    renderer = Renderer(args.adapter)
    ctx = renderer.ctx
    print(f"adapter: {ctx.name}", flush=True)
    peak = _peak(ctx)
    row = bench_backward(renderer, args.triangles, args.width, args.height, args.sigma, args.repeats,
                         progress=lambda: print(".", end="", flush=True))
    print()
    result = {"adapter": ctx.name, "adapter_info": {k: str(v) for k, v in ctx.info.items()},
              "timing": "timestamp queries" if ctx.features.timestamps else "host (per-stage submits)",
              "host": platform.node(), "date": time.strftime("%Y-%m-%d %H:%M:%S"), "peak": peak, "row": row,
              "backward_blend_flops_model": BACKWARD_BLEND_FLOPS}
    try:
        from .bench import git_commit
        result["commit"] = git_commit()
    except ImportError:  # pragma: no cover
        pass
    print(format_table(result))
    if args.json:
        out = Path(args.json)
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = out.with_suffix(out.suffix + ".tmp")
        tmp.write_text(json.dumps(result, indent=2, default=float))
        os.replace(tmp, out)
        print(f"wrote {out}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
