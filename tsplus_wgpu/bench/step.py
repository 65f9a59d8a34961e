"""``tsplus bench-step``: what a training step costs the host. A command, never a test.

On a GPU a step's kernels take 1-2 ms and the step about 26 ms (the H100 runs): the host's
recording of about 80 dispatches is the step. This benchmark trains a model so small that
the device has almost nothing to do (the procedural tiny scene, 64x48, from 60 points), so
the time per step is the host's. It runs blocks of steps with the context's host caching
(``GpuContext.host_caching``: uniform buffers by content, bind groups by their buffers, the
step's forward and backward on the renderer's scratch buffers, one submit for the backward's
stages) on and off in turn, in one process (off: every step's host work as before
2026-11-27), and reports the medians, their ratio, and how many bind groups and uniform
buffers a step made. Exactness: two fresh trainers, one per mode, train the same steps to
bit-identical parameters.
"""

from __future__ import annotations

import hashlib
import os
import platform
import statistics
import time

import numpy as np

from .measure import git_commit, timing_name


def _trainer(renderer, points, seed=0):
    from ..data.procedural import load_procedural
    from ..train.trainer import TrainConfig, Trainer
    scene = load_procedural("tiny", num_points=points)
    return Trainer(scene, TrainConfig(iterations=100_000, quick=True, log_every=0, topology=False, seed=seed),
                   renderer=renderer)


def _digest(t):
    c = t.ctx
    arrays = [c.read(t.params[k], np.float32, size) for k, size in
              (("positions", 3 * t.n), ("sh", 3 * t.n * t.k), ("logits", t.n))]
    return hashlib.sha1(b"".join(a.tobytes() for a in arrays)).hexdigest()[:16]


def _identical(renderer, points, steps):
    """Parameters after ``steps`` steps of two fresh trainers, caches off and on: equal?"""
    ctx, digests, before = renderer.ctx, [], renderer.ctx.host_caching
    try:
        for mode in (False, True):
            ctx.host_caching = mode
            t = _trainer(renderer, points)
            for _ in range(steps):
                t.step()
            digests.append(_digest(t))
    finally:
        ctx.host_caching = before
    return digests[0] == digests[1], digests[1]


def step_report(renderer, points=60, steps=20, blocks=8, warmup=20, log=None):
    """Medians of ``blocks`` blocks of ``steps`` steps per mode (caches on / off, alternating,
    after ``warmup`` steps), per-step counts of what was made, and the exactness check."""
    ctx, before = renderer.ctx, renderer.ctx.host_caching
    t = _trainer(renderer, points)
    for _ in range(warmup):
        t.step()
    ms = {True: [], False: []}
    made = [0, 0, 0]          # with the caches: steps, bind groups made, uniform buffers made
    try:
        _blocks(t, ctx, ms, made, steps, blocks, log)
    finally:
        ctx.host_caching = before
    same, digest = _identical(renderer, points, 2 * int(steps))
    on, off = statistics.median(ms[True]), statistics.median(ms[False])
    return {"adapter": ctx.name, "timing": timing_name(ctx), "commit": git_commit(),
            "python": platform.python_version(), "load_average": os.getloadavg()[0],
            "scene": f"procedural tiny 64x48 from {points} points", "vertices": int(t.n), "triangles": int(t.m),
            "steps_per_block": int(steps), "blocks": int(blocks),
            "ms_per_step_caches_on": on, "ms_per_step_caches_off": off, "ratio_off_over_on": off / on,
            "blocks_on": ms[True], "blocks_off": ms[False],
            "bind_groups_made_per_step": made[1] / max(made[0], 1),
            "uniforms_made_per_step": made[2] / max(made[0], 1),
            "identical_parameters": bool(same), "parameters_digest": digest}


def _blocks(t, ctx, ms, made, steps, blocks, log):
    """``blocks`` blocks of ``steps`` steps per mode, alternating which goes first; ms per step
    into ``ms[mode]``, and with the caching on, steps and what was made into ``made``."""
    for block in range(int(blocks)):
        for mode in ((True, False) if block % 2 else (False, True)):
            ctx.host_caching = mode
            ctx.wait()
            g0, u0 = ctx.binding_counts()
            t0 = time.perf_counter()
            for _ in range(int(steps)):
                t.step()
            ctx.wait()
            ms[mode].append((time.perf_counter() - t0) * 1e3 / steps)
            if mode:
                g1, u1 = ctx.binding_counts()
                made[0] += steps
                made[1] += g1 - g0
                made[2] += u1 - u0
        if log:
            log(f"block {block + 1}/{blocks}: host caching on {ms[True][-1]:.1f} ms/step, off {ms[False][-1]:.1f}")


def format_step(r):
    """The report of :func:`step_report` as text."""
    return "\n".join([
        f"adapter: {r['adapter']}   commit {r['commit']}   load average {r['load_average']:.2f}",
        f"scene: {r['scene']} ({r['vertices']:,} vertices, {r['triangles']:,} triangles); medians of "
        f"{r['blocks']} blocks of {r['steps_per_block']} steps per mode, alternating",
        f"host caching on:  {r['ms_per_step_caches_on']:.1f} ms/step ({r['bind_groups_made_per_step']:.1f} bind groups and "
        f"{r['uniforms_made_per_step']:.1f} uniform buffers made a step)",
        f"host caching off: {r['ms_per_step_caches_off']:.1f} ms/step (every bind group, uniform and "
        f"forward/backward buffer made anew, the backward's stages submitted one by one)",
        f"off / on: {r['ratio_off_over_on']:.2f}x; parameters after the same steps "
        f"{'bit-identical' if r['identical_parameters'] else 'DIFFERENT'} in both modes"])


__all__ = ["step_report", "format_step"]
