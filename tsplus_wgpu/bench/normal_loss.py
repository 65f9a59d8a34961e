"""The per-step cost of the optional normal loss (:class:`~tsplus_wgpu.train.normals.NormalLoss`):
``python -m tsplus_wgpu.bench.normal_loss [tiny|small|demo] [pairs]``."""

from __future__ import annotations

import time

import numpy as np

from ..data import load_procedural
from ..data.normals import prepare_prior
from ..data.procedural import normal_maps
from ..render.renderer import Renderer
from ..train.trainer import TrainConfig, Trainer


def bench_step_cost(size="tiny", reps=10, warm=600, adapter=None):
    """Per-step cost of the normal loss: a quick-preset trainer on the procedural scene
    (``size``, its true normal maps, topology off so the mesh stays fixed) trained to ``warm``
    of 3000 iterations (normal loss on from 501), then ``reps`` pairs of steps with and without
    the normal loss, interleaved (so load from other processes hits both alike). Returns
    ``dict(with_ms, without_ms, cost_ms, triangles, vertices)`` (medians, host wall time with a
    queue wait after each step)."""
    sc = load_procedural(size)
    pri = [prepare_prior(m) if v in sc.train_indices else None for v, m in enumerate(normal_maps(sc))]
    r = Renderer(adapter)
    t = Trainer(sc, TrainConfig(iterations=3000, quick=True, topology=False, background=sc.background), renderer=r,
                normals=pri)
    t.train(progress=False, until=warm, log_every=0)
    maps, c = t.normal_maps, r.ctx
    times = {True: [], False: []}
    for _ in range(int(reps)):
        for on in (True, False):
            t.normal_maps = maps if on else None
            c.wait()
            t0 = time.perf_counter()
            t.step()
            c.wait()
            times[on].append(time.perf_counter() - t0)
    t.normal_maps = maps
    w, wo = 1e3 * float(np.median(times[True])), 1e3 * float(np.median(times[False]))
    return dict(size=size, with_ms=w, without_ms=wo, cost_ms=w - wo, triangles=t.m, vertices=t.n,
                adapter=r.adapter_name)


if __name__ == "__main__":   # python -m tsplus_wgpu.bench.normal_loss [tiny|small|demo] [pairs]
    import sys
    res = bench_step_cost(sys.argv[1] if len(sys.argv) > 1 else "tiny", int(sys.argv[2]) if len(sys.argv) > 2 else 10)
    print(f"{res['adapter']}: procedural:{res['size']} ({res['triangles']} triangles, {res['vertices']} vertices): "
          f"step {res['without_ms']:.1f} ms without the normal loss, {res['with_ms']:.1f} ms with "
          f"(+{res['cost_ms']:.1f} ms; medians of interleaved steps)")
