"""Measurements shared by the benchmarks: the device's peak FMA rate, the blend kernels'
FLOP counts, the forward and backward blend timed on a trained model, a synthetic scene of
random triangles, the commit, and median / min-max summaries."""

from __future__ import annotations

import math
import os
import statistics
import subprocess
import time
from pathlib import Path

import numpy as np

from ..gpu.context import GpuContext
from ..gpu.recorder import host_time
from ..types import Camera, TriangleModel

#: The forward blend's arithmetic, counted per pixel from the algorithm (not from the compiled
#: code), with a transcendental counted as one operation:
#:   every pair evaluation: d = p - s (2), three edge values 1 + g.d (3 x 4), two min (2);
#:   evaluations with ratio >= tau: log2, times sigma, exp2, times opacity, cap (5);
#:   contributions: T (1 - alpha) (2), colour c + cx dx + cy dy (3 x 4), w = alpha T (1),
#:   C += c w (3 x 2).
#: The kernel counts the three kinds of work (ForwardResult.work).
BLEND_FLOPS = {"evaluations": 16, "powered": 5, "contributions": 21}

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


def blend_flops(work):
    """FLOPs of the forward blend for ``work`` (ForwardResult.work), by :data:`BLEND_FLOPS`."""
    return sum(BLEND_FLOPS[k] * work[k] for k in BLEND_FLOPS)


def backward_blend_flops(work):
    """FLOPs of the backward blend for ``work``, by :data:`BACKWARD_BLEND_FLOPS`."""
    return sum(BACKWARD_BLEND_FLOPS[k] * work[k] for k in BACKWARD_BLEND_FLOPS)


def backward_blend_work(ctx, grads):
    """The backward blend's work counters (evaluations, powered, contributions) of a profiled
    backward pass ``grads`` (zeros when it kept no ``work`` buffer)."""
    if "work" not in getattr(grads, "buffers", {}):
        return dict(evaluations=0, powered=0, contributions=0)
    w = ctx.read(grads.buffers["work"], np.uint32, 3)
    return dict(evaluations=int(w[0]), powered=int(w[1]), contributions=int(w[2]))


def git_commit():
    """The checkout's short commit ('unknown' outside a git checkout)."""
    try:
        here = Path(__file__).resolve().parent.parent
        out = subprocess.run(["git", "-C", str(here), "rev-parse", "--short", "HEAD"], capture_output=True,
                             text=True, timeout=5)
        return out.stdout.strip() or "unknown"
    except Exception:
        return "unknown"


def timing_name(ctx, host="host timing"):
    """How per-stage times are taken on ``ctx``: timestamp queries where supported, else ``host``."""
    return "timestamp queries" if ctx.features.timestamps else host


# ---------------------------------------------------------------------------------------- summaries

def finite(x):
    """True for a finite int or float."""
    return x is not None and isinstance(x, (int, float)) and math.isfinite(float(x))


def stats(values):
    """Median, min, max and count of the finite ``values`` (None when there are none)."""
    v = [float(x) for x in values if finite(x)]
    if not v:
        return None
    return dict(median=statistics.median(v), min=min(v), max=max(v), n=len(v))


# ---------------------------------------------------------------------------------------- peak

def stage_medians(runs):
    """Per-stage medians of ``runs``, a list of ``{stage: ms}`` dicts (the first one's stages;
    a stage missing from a run counts 0)."""
    return {k: statistics.median(r.get(k, 0.0) for r in runs) for k in runs[0]}


def measure_peak_flops(ctx: GpuContext, repeats=5, target_s=0.15):
    """Peak FMA throughput (FLOP/s) of ``ctx``'s device, by ``shaders/bench/peak_fma.wgsl``:
    8 independent vec4 FMA chains per invocation. Median of ``repeats``."""
    from ..kernels.bench import PeakFma
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
    flops = stage.flop(groups, iters)
    med = statistics.median(times)
    return {"flops_per_s": flops / med, "seconds_median": med, "seconds_all": times, "iterations": iters,
            "invocations": groups * stage.invocations}


def peak_record(ctx, repeats):
    """One peak FMA sample for a report: median rate, min-max over the repeats, time and load."""
    p = measure_peak_flops(ctx, repeats=repeats)
    s = [p["flops_per_s"] * p["seconds_median"] / t for t in p["seconds_all"]]
    return dict(flops_per_s=p["flops_per_s"], flops_per_s_min=min(s), flops_per_s_max=max(s),
                repeats=len(s), at=time.strftime("%H:%M:%S"), loadavg=list(os.getloadavg()))


# ---------------------------------------------------------------------------------------- blend

def _time_blend(renderer, model, cam, sigma, bg, near, vi, repeats):
    """``repeats`` profiled forward + backward passes: per-pass kernel and wall times (ms)."""
    from ..render.backward import backward
    c = renderer.ctx
    t = dict(forward=[], backward=[], forward_wall=[], forward_sum=[])
    res = g = None
    for _ in range(repeats):
        c.wait()
        ts = time.perf_counter()
        res = renderer.forward(model, cam, sigma, bg, near, profile=True)
        c.wait()
        t["forward_wall"].append((time.perf_counter() - ts) * 1e3)
        t["forward_sum"].append(sum(res.timings.values()))
        t["forward"].append(res.timings.get("rasterize_forward", float("nan")))
        g = backward(renderer, res, vi, profile=True)
        t["backward"].append(g.timings.get("rasterize_backward", float("nan")))
    return t, res, g


def _kernel_rates(name, ms, flops, work, peak):
    """One blend kernel's record: ms, FLOPs, GFLOP/s and fraction of ``peak`` (median, min, max)."""
    rate = [flops / (m * 1e-3) for m in ms if finite(m) and m > 0]
    p = peak["flops_per_s"]
    return dict(kernel=f"rasterize_{name}", ms=stats(ms), flops=flops, work=work,
                gflops_per_s=statistics.median(rate) / 1e9 if rate else None,
                fraction_of_peak=statistics.median(rate) / p if rate else None,
                fraction_min=min(rate) / p if rate else None,
                fraction_max=max(rate) / p if rate else None)


def measure_blend(renderer, trainer, repeats, peak):
    """The forward and backward blend kernels on ``trainer``'s model (first training view, its
    current sigma, in the trainer's frame), timed by timestamp queries (host timing otherwise), with ``peak()`` (a peak
    FMA record, :func:`peak_record`) measured just before: GFLOP/s of the algorithm's count and
    the fraction of peak."""
    from ..render.backward import backward
    t = trainer
    view = t.train_views[0]
    cam = t.scene.cameras[view]
    sigma = t.sched.sigma(t.iteration)
    bg, near = t.config.background, t.config.near
    vi = np.random.default_rng(1).normal(size=(cam.height, cam.width, 3)).astype(np.float32)
    res = renderer.forward(t.model, cam, sigma, bg, near)
    backward(renderer, res, vi)                                         # warm-up
    pk = peak()
    ms, res, g = _time_blend(renderer, t.model, cam, sigma, bg, near, vi, repeats)
    fwork = res.work
    bwork = backward_blend_work(renderer.ctx, g)
    out = dict(view=int(view), width=cam.width, height=cam.height, sigma=sigma, triangles=t.m, pairs=res.num_pairs,
               timing=timing_name(renderer.ctx), peak=pk,
               forward_wall_ms=stats(ms["forward_wall"]), forward_stages_sum_ms=stats(ms["forward_sum"]),
               # the stages' sum against the host's wall clock: timestamps that account for less than
               # a tenth of it are not to be trusted (see bench.runs: lavapipe after a render pass)
               timestamps_plausible=bool(statistics.median(ms["forward_sum"])
                                         >= 0.1 * statistics.median(ms["forward_wall"])))
    out["forward"] = _kernel_rates("forward", ms["forward"], blend_flops(fwork), fwork, pk)
    out["backward"] = _kernel_rates("backward", ms["backward"], backward_blend_flops(bwork), bwork, pk)
    return out


# ---------------------------------------------------------------------------------------- scene

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


__all__ = ["BLEND_FLOPS", "BACKWARD_BLEND_FLOPS", "blend_flops", "backward_blend_flops", "backward_blend_work",
           "git_commit", "timing_name", "finite", "stats", "stage_medians", "measure_peak_flops", "peak_record", "measure_blend",
           "synthetic_scene"]
