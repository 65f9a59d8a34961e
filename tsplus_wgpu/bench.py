"""Benchmarks (commands, never tests): the device's peak FMA rate and the forward
rasterizer's per-stage cost. Every timing is a median of repeats, names the adapter,
and stands next to an exactness figure (the image against the float64 twin)."""

from __future__ import annotations

import json
import os
import platform
import statistics
import subprocess
import time
from pathlib import Path

import numpy as np

from .gpu import GpuContext, host_time
from .types import Camera, TriangleModel

#: The blend's arithmetic, counted per pixel from the algorithm (not from the compiled
#: code), with a transcendental counted as one operation:
#:   every pair evaluation: d = p - s (2), three edge values 1 + g.d (3 x 4), two min (2);
#:   evaluations with ratio >= tau: log2, times sigma, exp2, times opacity, cap (5);
#:   contributions: T (1 - alpha) (2), colour c + cx dx + cy dy (3 x 4), w = alpha T (1),
#:   C += c w (3 x 2).
#: The kernel counts the three kinds of work (ForwardResult.work).
BLEND_FLOPS = {"evaluations": 16, "powered": 5, "contributions": 21}


def blend_flops(work):
    return sum(BLEND_FLOPS[k] * work[k] for k in BLEND_FLOPS)


def git_commit():
    try:
        here = Path(__file__).resolve().parent.parent
        out = subprocess.run(["git", "-C", str(here), "rev-parse", "--short", "HEAD"], capture_output=True,
                             text=True, timeout=5)
        return out.stdout.strip() or "unknown"
    except Exception:
        return "unknown"


def measure_peak_flops(ctx: GpuContext, repeats=5, target_s=0.15):
    """Peak FMA throughput (FLOP/s) of ``ctx``'s device, by ``shaders/peak_fma.wgsl``:
    8 independent vec4 FMA chains per invocation. Median of ``repeats``."""
    from .stages import PeakFma
    stage = PeakFma(ctx)
    sink = ctx.buffer(16 * 256, "peak_sink")
    # lavapipe ends loops after 65535 iterations per invocation: keep the loop below that
    # and grow the number of workgroups instead
    # (a GPU needs many workgroups in flight; a CPU driver few)
    iters = 50_000 if ctx.is_cpu else 1000
    groups = 16 if ctx.is_cpu else 8192

    def run():
        enc = ctx.device.create_command_encoder()
        pp = stage.uniform("PeakParams", iterations=iters)
        stage.dispatch(enc, groups, dict(pp=pp, sink=sink))
        ctx.queue.submit([enc.finish()])

    # grow the work (iterations first, then workgroups) until one run takes about target_s
    while True:
        dt = host_time(ctx, run)
        if dt >= target_s or groups >= 1 << 22:
            break
        grow = min(16.0, max(2.0, target_s / max(dt, 1e-6)))
        if iters < 50_000:
            iters = min(50_000, int(iters * grow))
        else:
            groups = int(groups * grow)
    times = [host_time(ctx, run) for _ in range(repeats)]
    flops = groups * 256 * iters * 8 * 4 * 2
    med = statistics.median(times)
    return {"flops_per_s": flops / med, "seconds_median": med, "seconds_all": times, "iterations": iters,
            "invocations": groups * 256}


def synthetic_scene(num_triangles, width=640, height=480, depth_complexity=8.0, opacity=0.5, seed=0):
    """Random triangles in front of a camera, sized so that on average every pixel is
    covered by ``depth_complexity`` of them; vertices shared along strips."""
    rng = np.random.default_rng(seed)
    f = 0.8 * width
    cam = Camera(width, height, f, f, width / 2, height / 2, np.eye(4))
    m = int(num_triangles)
    area_px = depth_complexity * width * height / m
    radius_px = np.sqrt(area_px / 1.3)        # equilateral-ish triangle of that area
    z = rng.uniform(2.0, 6.0, m)
    cx = rng.uniform(-0.05 * width, 1.05 * width, m)
    cy = rng.uniform(-0.05 * height, 1.05 * height, m)
    ang = rng.uniform(0, 2 * np.pi, m)
    verts = []
    for k in range(3):
        a = ang + k * 2 * np.pi / 3 + rng.normal(0, 0.2, m)
        r = radius_px * rng.uniform(0.7, 1.3, m)
        u = cx + r * np.cos(a)
        v = cy + r * np.sin(a)
        zz = z + rng.normal(0, 0.05, m)
        verts.append(np.stack([(u - width / 2) * zz / f, (v - height / 2) * zz / f, zz], 1))
    # parameters rounded to float32, so that the twin and the kernel start from the same numbers
    pos = np.stack(verts, 1).reshape(-1, 3).astype(np.float32).astype(np.float64)
    tri = np.arange(3 * m).reshape(m, 3)
    n = pos.shape[0]
    sh = np.zeros((n, 1, 3))
    sh[:, 0] = rng.uniform(-1.5, 1.5, (n, 3)).astype(np.float32)
    return TriangleModel(pos, tri, sh, np.full(n, opacity)), cam


def bench_raster(renderer, counts=(10_000, 100_000, 1_000_000), width=640, height=480, sigma=0.5, repeats=5,
                 check_exact_up_to=10_000, progress=None):
    from . import reference
    rows = []
    for m in counts:
        model, cam = synthetic_scene(m, width, height)
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
        if m <= check_exact_up_to:
            ref = reference.render(model, cam, sigma)
            ok = ~ref.ambiguous
            err = np.abs(last.image - ref.image).max(axis=-1)
            row["max_abs_error_vs_twin"] = float(err[ok].max())
            row["share_within_1e-5"] = float((err[ok] <= 1e-5).mean())
            row["pixels_compared"] = int(ok.sum())
        rows.append(row)
    return rows


def format_table(result):
    lines = []
    peak = result["peak"]["flops_per_s"]
    lines.append(f"adapter: {result['adapter']}   commit: {result['commit']}   timing: {result['timing']}")
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


def run_bench_raster(args):
    from tqdm import tqdm

    from .renderer import Renderer
    renderer = Renderer(args.adapter)
    ctx = renderer.ctx
    counts = [int(c) for c in args.triangles]
    print(f"adapter: {ctx.name}", flush=True)
    peak = measure_peak_flops(ctx)
    print(f"peak FMA rate: {peak['flops_per_s'] / 1e9:.1f} GFLOP/s", flush=True)
    with tqdm(total=len(counts) * args.repeats, desc="forward", unit="run", dynamic_ncols=True) as bar:
        rows = bench_raster(renderer, counts, args.width, args.height, args.sigma, args.repeats,
                            progress=bar.update)
    result = {
        "adapter": ctx.name, "adapter_info": {k: str(v) for k, v in ctx.info.items()},
        "timing": "timestamp queries" if ctx.features.timestamps else "host (per-stage submits)",
        "commit": git_commit(), "host": platform.node(), "python": platform.python_version(),
        "date": time.strftime("%Y-%m-%d %H:%M:%S"), "peak": peak, "rows": rows,
        "blend_flops_model": BLEND_FLOPS,
    }
    print(format_table(result))
    if args.json:
        out = Path(args.json)
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = out.with_suffix(out.suffix + ".tmp")
        tmp.write_text(json.dumps(result, indent=2))
        os.replace(tmp, out)
        print(f"wrote {out}")
    return 0
