"""``tsplus bench-scale``: forward + backward of paper-sized models (SH degree 3, 0.5M-3M
vertices, 1920x1080 by default), one row per size: per-stage milliseconds, the device memory
its buffers hold, tile-triangle pairs per pixel, what training that model would need
(``train/memory.py``), and the forward image against the float64 twin on a crop (within
1e-5 plus the twin's first-order float32 bound ``f32_bound``, as the tests compare them). A size that
does not fit the device (a buffer over its storage-binding limit) is a row that says which
buffer and by how much, not a crash. A command, never a test.

The model (:func:`scale_scene`) is what a trained scene looks like to the renderer: surfaces
of shared vertices, about 2 triangles a vertex, several layers deep, filling the view."""

from __future__ import annotations

import gc
import math
import platform
import statistics
import time
from types import SimpleNamespace

import numpy as np

from ..kernels.blend import kernel_layout
from ..types import Camera, TriangleModel
from .measure import git_commit, stage_medians, timing_name

#: the vertex counts measured by default (issue 13: the paper's scenes end near 2M, its cap is 3M)
SCALE_SIZES = (500_000, 1_000_000, 2_000_000, 3_000_000)
#: side of the square crop compared with the float64 twin (pixels)
CROP = 32


def scale_scene(num_vertices, width=1920, height=1080, sh_degree=3, layers=3, opacity=0.6, seed=0):
    """``(model, camera)``: ``layers`` wavy grids at depths 2 to 6 filling the camera's view
    (each a little wider than the frustum), about ``num_vertices`` vertices in all, two
    triangles a grid cell, SH of degree ``sh_degree`` with random coefficients. Parameters
    are rounded to float32 so that kernel and twin start from the same numbers."""
    rng = np.random.default_rng(seed)
    f = 0.8 * width
    cam = Camera(width, height, f, f, width / 2, height / 2, np.eye(4))
    per = max(4, int(num_vertices) // int(layers))
    nx = max(2, int(round(math.sqrt(per * width / height))))
    ny = max(2, per // nx)
    pos, tri = [], []
    u, v = np.meshgrid(np.linspace(-1.05, 1.05, nx), np.linspace(-1.05, 1.05, ny))
    for k, z0 in enumerate(np.linspace(2.0, 6.0, int(layers))):
        z = z0 + 0.15 * np.sin(3.0 * u + k) * np.cos(2.0 * v - k)
        p = np.stack([u * z * width / (2 * f), v * z * height / (2 * f), z], -1).reshape(-1, 3)
        idx = np.arange(nx * ny).reshape(ny, nx)
        a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
        tri.append(np.concatenate([np.stack([a, b, c], 1), np.stack([b, d, c], 1)]) + k * nx * ny)
        pos.append(p)
    pos = np.concatenate(pos).astype(np.float32).astype(np.float64)
    n, kk = len(pos), (int(sh_degree) + 1) ** 2
    sh = np.zeros((n, kk, 3))
    sh[:, 0] = rng.uniform(-1.2, 1.2, (n, 3))
    if kk > 1:
        sh[:, 1:] = rng.normal(0.0, 0.1, (n, kk - 1, 3))
    sh = sh.astype(np.float32).astype(np.float64)
    return TriangleModel(pos, np.concatenate(tri), sh, np.full(n, float(opacity))), cam


def crop_twin(reference_render, model, camera, sigma, x0, y0, size=CROP):
    """The twin's forward ``image``, ``ambiguous`` and ``f32_bound`` on the ``size`` x ``size``
    pixels at ``(x0, y0)`` of ``camera``, and how many triangles it drew: the triangles whose
    projected bounds touch the crop (2 px margin), drawn by the whole camera, so that pixel
    coordinates (and the twin's float32 error model, which grows with them) are the kernel's."""
    uv = camera.project(model.positions)[0]
    px, py = uv[:, 0], uv[:, 1]
    t = model.triangles
    lo_x, hi_x = px[t].min(1), px[t].max(1)
    lo_y, hi_y = py[t].min(1), py[t].max(1)
    keep = (hi_x >= x0 - 2) & (lo_x <= x0 + size + 2) & (hi_y >= y0 - 2) & (lo_y <= y0 + size + 2)
    sub = t[keep]
    used = np.unique(sub)
    remap = np.full(model.num_vertices, -1, np.int64)
    remap[used] = np.arange(len(used))
    part = TriangleModel(model.positions[used], remap[sub], model.sh[used], model.opacity[used])
    full = reference_render(part, camera, sigma)
    window = (slice(y0, y0 + size), slice(x0, x0 + size))
    out = SimpleNamespace(image=full.image[window], ambiguous=full.ambiguous[window], f32_bound=full.f32_bound[window])
    return out, int(keep.sum())


def scale_row(renderer, num_vertices, width, height, sh_degree=3, sigma=0.5, repeats=1, reference_render=None):
    """One size: forward + backward ``repeats`` times (medians), memory, pairs, twin on a crop;
    ``refused`` (the one-line reason) where a buffer of the forward does not fit the device,
    ``backward_refused`` where one of the backward's does not (the forward's figures stand)."""
    from ..render.backward import backward, pair_window_capacity, pair_windows
    from ..train.memory import training_bytes
    ctx = renderer.ctx
    model, cam = scale_scene(num_vertices, width, height, sh_degree)
    m = len(model.triangles)
    row = {"vertices": model.num_vertices, "triangles": m, "sh_degree": int(sh_degree), "width": width,
           "height": height}
    rng = np.random.default_rng(1)
    vi = rng.normal(size=(height, width, 3)).astype(np.float32)
    gc.collect()                   # buffers of earlier sizes freed now, not while this one is measured
    ctx.reset_peak()
    before = ctx.live_bytes()
    fwd, bwd, walls = [], [], []
    try:
        for _ in range(max(1, int(repeats))):
            ctx.wait()
            t0 = time.perf_counter()
            res = renderer.forward(model, cam, sigma, profile=True)
            fwd.append(res.timings)
            try:
                g = backward(renderer, res, vi, None, profile=True)
            except ValueError as exc:
                row["backward_refused"] = str(exc)
                walls.append(time.perf_counter() - t0)
                break
            walls.append(time.perf_counter() - t0)
            bwd.append(g.timings)
    except ValueError as exc:      # GpuContext.check_size: a buffer over the storage-binding limit
        row["refused"] = str(exc)
        return row
    wins = renderer.tri_windows(m, res.num_pairs, res.max_tile_pairs)
    row.update(forward_stage_ms=stage_medians(fwd), backward_stage_ms=stage_medians(bwd) if bwd else {},
               forward_windows=1 if wins is None else len(wins),
               wall_ms=1e3 * statistics.median(walls),
               pairs=int(res.num_pairs), pairs_per_pixel=res.num_pairs / (width * height),
               device_bytes_peak=ctx.peak_bytes() - before)
    row["forward_ms"] = sum(row["forward_stage_ms"].values())
    row["backward_ms"] = sum(row["backward_stage_ms"].values()) if bwd else None
    cap = pair_window_capacity(ctx)
    if bwd:
        row["pair_windows"] = len(pair_windows(res.num_pairs, res.max_tile_pairs, cap))
    row["training_bytes_estimate"] = training_bytes(model.num_vertices, m, sh_degree, width, height,
                                                    int(res.num_pairs), pair_window=cap,
                                                    max_binding=int(ctx.limits["max-storage-buffer-binding-size"]))["total"]
    if reference_render is not None:
        x0, y0 = (width - CROP) // 2, (height - CROP) // 2
        ref, drawn = crop_twin(reference_render, model, cam, sigma, x0, y0)
        img = np.asarray(res.image)[y0:y0 + CROP, x0:x0 + CROP]
        err = np.abs(img - ref.image).max(-1)
        ok = ~ref.ambiguous
        excess = (err - 1e-5 - ref.f32_bound)[ok]      # the twin's float32 error model, as the tests use it
        row.update(crop_triangles=drawn, crop_max_abs_error=float(err[ok].max()),
                   crop_share_within_1e_5=float((err[ok] <= 1e-5).mean()),
                   crop_share_within_f32_model=float((excess <= 0).mean()), crop_max_excess=float(excess.max()))
    return row


def scale_report(renderer, sizes=SCALE_SIZES, width=1920, height=1080, sh_degree=3, sigma=0.5, repeats=1,
                 reference_render=None, log=None):
    """Every size of ``sizes`` (:func:`scale_row`), with the adapter, its binding limit and the commit."""
    ctx = renderer.ctx
    rows = []
    for n in sizes:
        rows.append(scale_row(renderer, n, width, height, sh_degree, sigma, repeats, reference_render))
        if log:
            log(format_row(rows[-1]))
    return {"adapter": ctx.name, "timing": timing_name(ctx),
            "storage_binding_bytes": int(ctx.limits["max-storage-buffer-binding-size"]),
            "layout": kernel_layout(ctx), "commit": git_commit(), "python": platform.python_version(),
            "sigma": sigma, "repeats": int(repeats), "rows": rows}


def _gib(b):
    return f"{b / 2**30:.2f} GiB"


def format_row(r):
    """One size as a line."""
    head = f"{r['vertices']:>10,} v {r['triangles']:>10,} t"
    if "refused" in r:
        return f"{head}  refused: {r['refused']}"
    twin = (f"; crop vs twin: max {r['crop_max_abs_error']:.1e}, {100 * r['crop_share_within_1e_5']:.1f} % <= 1e-5, "
            f"{100 * r['crop_share_within_f32_model']:.1f} % within 1e-5 + the twin's float32 bound"
            if "crop_max_abs_error" in r else "")
    fw = r.get("forward_windows", 1)
    bw = (f"backward refused: {r['backward_refused']}" if r.get("backward_refused")
          else f"backward {r['backward_ms']:,.1f} ms")
    return (f"{head}  forward {r['forward_ms']:,.1f} ms" + (f" in {fw} windows of gathered triangles" if fw > 1 else "")
            + f", {bw} (wall {r['wall_ms']:,.0f}); {r['pairs_per_pixel']:.2f} pairs/px"
            + (f" in {r['pair_windows']} backward windows" if r.get("pair_windows", 1) > 1 else "")
            + f"; buffers {_gib(r['device_bytes_peak'])}, training needs about "
            f"{_gib(r['training_bytes_estimate'])}{twin}")


def format_table(result):
    """The report as text: the conditions, one line per size, then the stages of the largest size that ran."""
    out = [f"adapter: {result['adapter']}   timing: {result['timing']}   kernel layout: {result['layout']}",
           f"storage binding: {result['storage_binding_bytes'] / 2**20:,.0f} MiB   sigma {result['sigma']}   "
           f"medians of {result['repeats']}   commit {result['commit']}", ""]
    out += [format_row(r) for r in result["rows"]]
    ran = [r for r in result["rows"] if "refused" not in r]
    if ran:
        r = ran[-1]
        out += ["", f"stages at {r['vertices']:,} vertices (ms):"]
        out += [f"  forward  {k:<24}{v:>12.2f}" for k, v in r["forward_stage_ms"].items()]
        out += [f"  backward {k:<24}{v:>12.2f}" for k, v in r["backward_stage_ms"].items()]
    return "\n".join(out)


def scale_training(renderer, num_vertices, width=960, height=540, iterations=50, sh_degree=3, views=4,
                   folder=None, log=None):
    """The first ``iterations`` steps of a paper-preset run of a paper-sized model at ``width`` x
    ``height`` (issue 13: 3M vertices, 960x540, 50 steps): half of them, a checkpoint written to
    ``folder``, a new trainer resumed from it, the other half. The targets are the model's own
    renders from ``views`` cameras side by side; training starts from it with its DC colours
    shuffled between vertices, so the loss must fall. Returns a dict: vertices, triangles, ms a
    step (median of each half), the loss at the first and last step, the device's peak bytes,
    the checkpoint's bytes and seconds to write and to resume."""
    import tempfile
    from pathlib import Path

    from ..data.scene import Scene
    from ..train.trainer import TrainConfig, Trainer
    ctx = renderer.ctx
    model, cam = scale_scene(num_vertices, width, height, sh_degree)
    cams = []
    for i in range(int(views)):
        w2c = np.array(cam.world_to_camera, np.float64)
        w2c[0, 3] = 0.08 * (i - (views - 1) / 2)          # side by side, 8 cm apart at depth 2-6
        cams.append(Camera(width, height, cam.fx, cam.fy, cam.cx, cam.cy, w2c))
    images = [np.clip(renderer.forward(model, c, 0.5).image, 0.0, 1.0).astype(np.float32) for c in cams]
    scene = Scene("procedural", cams, images, [f"view_{i}" for i in range(len(cams))],
                  train_indices=list(range(len(cams))), test_indices=[0])
    start = TriangleModel(model.positions, model.triangles, model.sh.copy(), model.opacity)
    start.sh[:, 0] = start.sh[np.random.default_rng(7).permutation(model.num_vertices), 0]
    cfg = TrainConfig(quick=False, topology=False, log_every=0, seed=0)
    half = max(1, int(iterations) // 2)
    ctx.reset_peak()
    out = dict(vertices=model.num_vertices, triangles=model.num_triangles, width=width, height=height,
               iterations=int(iterations))
    with tempfile.TemporaryDirectory(dir=folder) as tmp:
        t = Trainer(scene, cfg, renderer=renderer, model=start)
        times = []
        for i in range(half):
            t0 = time.perf_counter()
            stats = t.step(read_stats=i == 0)
            times.append(time.perf_counter() - t0)
            if i == 0:
                out["loss_first"] = stats["loss"]
            if log and (i + 1) % 5 == 0:
                log(f"  step {i + 1}: {1e3 * statistics.median(times):,.0f} ms a step")
        path = Path(tmp) / "checkpoint.npz"
        t0 = time.perf_counter()
        t.save_checkpoint(path)
        out["checkpoint_s"], out["checkpoint_bytes"] = time.perf_counter() - t0, path.stat().st_size
        del t
        t0 = time.perf_counter()
        t = Trainer.resume(path, scene, cfg, renderer=renderer)
        out["resume_s"] = time.perf_counter() - t0
        later = []
        for i in range(half, int(iterations)):
            t0 = time.perf_counter()
            stats = t.step(read_stats=i == int(iterations) - 1)
            later.append(time.perf_counter() - t0)
        out["loss_last"] = stats["loss"] if stats else None
        out["iteration"] = t.iteration
    out.update(ms_per_step=1e3 * statistics.median(times), ms_per_step_resumed=1e3 * statistics.median(later or [0]),
               device_bytes_peak=ctx.peak_bytes())
    return out


__all__ = ["SCALE_SIZES", "CROP", "scale_scene", "crop_twin", "scale_row", "scale_report", "format_row",
           "format_table", "scale_training"]
