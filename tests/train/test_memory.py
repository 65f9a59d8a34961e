"""What training costs in device memory (docs/memory.md): the estimate of
:mod:`tsplus_wgpu.train.memory` against the device buffers a real training step holds, counted by
the context's tally (:meth:`GpuContext.live_bytes` / :meth:`GpuContext.peak_bytes`)."""

from __future__ import annotations

import gc

import numpy as np
import pytest

from tsplus_wgpu.train.memory import FAMILIES, largest_model, training_buffers, training_bytes

#: How far the peak of a step may be from the estimate (relative). Measured on lavapipe: within
#: 0.4 % at every step. What is not in the estimate: the uniform buffers alive at the peak (a few
#: hundred bytes), and pair-sized scratch kept from an earlier view with more pairs (the sorts'
#: and segmented sums' scratch only grows, by 1.5x when that is more). Smaller than every family
#: the test asserts on (``FAMILIES`` but ``other``), so forgetting one fails.
TOL = 0.01


def test_tally_counts_buffers_until_they_are_dropped(ctx):
    gc.collect()
    before = ctx.live_bytes()
    buf = ctx.buffer(1000, "tally_test")               # rounded up to whole vec4s
    up = ctx.upload(np.arange(5, dtype=np.uint32), "tally_up")       # 20 bytes: 32
    assert ctx.live_bytes() - before == 1008 + 32
    assert ctx.peak_bytes() >= ctx.live_bytes()
    del buf, up
    assert ctx.live_bytes() == before
    ctx.reset_peak()
    assert ctx.peak_bytes() == before


def test_training_step_matches_the_estimate(renderer, monkeypatch):
    from tsplus_wgpu import Renderer
    from tsplus_wgpu.data import load_procedural
    from tsplus_wgpu.train import TrainConfig, Trainer

    # a renderer of its own on the session's device: its scratch holds no buffers sized by
    # earlier tests (the session renderer's does)
    r = Renderer(renderer.ctx)
    ctx = r.ctx
    views = []                                         # (pairs, rows, rendered width) per forward
    forward = r.forward

    def counting_forward(*args, **kwargs):
        res = forward(*args, **kwargs)
        views.append((res.num_pairs, res.buffers["counts"].size // 4, res.camera.width))
        return res

    monkeypatch.setattr(r, "forward", counting_forward)
    scene = load_procedural("tiny")
    gc.collect()
    gc.disable()                 # no other test's garbage freed inside the measurement
    try:
        base = ctx.live_bytes()  # what earlier tests still hold; not ours
        t = Trainer(scene, TrainConfig(iterations=5, quick=True), renderer=r)
        seen, checked = set(), []
        for it in range(1, 6):   # quick, 5 iterations: s = 1, 1, 2, 4, 4 (the supersampled phase too)
            ctx.reset_peak()
            t.step()
            peak = ctx.peak_bytes() - base
            view = t.view_of(it)
            seen.add(view)
            cam = t.scene.cameras[view]
            # the forward's and backward's buffers are the renderer's scratch in training, kept
            # at the largest view's size so far
            pairs, rows = max(v[0] for v in views), max(v[1] for v in views)
            rendered = views[-1][2]
            assert not t.is_topology_step(it)
            est = training_bytes(t.n, t.m, t.config.sh_degree, cam.width, cam.height, pairs,
                                 supersample=rendered // cam.width, rows=rows, views=len(seen))
            checked.append((it, rendered // cam.width, peak, est))
            assert abs(peak - est["total"]) <= TOL * est["total"], (
                f"iteration {it}: peak {peak:,} bytes, estimate {est}")
    finally:
        gc.enable()
    assert {s for _, s, _, _ in checked} == {1, 2, 4}
    last = checked[-1][3]
    small = {f: last[f] for f in FAMILIES if f != "other" and last[f] <= TOL * last["total"]}
    assert not small, f"families under the tolerance, a test that would not notice them missing: {small}"


def _slope(family, name, x, **fixed):
    """Bytes of ``family`` per unit of argument ``name`` (at ``x``: the small terms' rounding aside)."""
    args = dict(num_vertices=0, num_triangles=0, sh_degree=3, width=1, height=1, pairs=0, views=0) | fixed
    return (training_bytes(**(args | {name: 2 * x}))[family] - training_bytes(**(args | {name: x}))[family]) / x


def test_the_coefficients_docs_memory_quotes():
    assert _slope("vertex", "num_vertices", 2**20) == 152 + 48 * 16          # SH degree 3: K = 16
    assert _slope("vertex", "num_vertices", 2**20, sh_degree=0) == 152 + 48
    assert _slope("triangle", "num_triangles", 3 * 2**20) == pytest.approx(352.0, abs=0.05)
    # past one binding of corner gradients the segmented sum's scratch comes back (1.7 a triangle)
    big = _slope("triangle", "num_triangles", 3 * 2**20, max_binding=2**27)
    assert big == pytest.approx(353.7, abs=0.05)
    assert _slope("pair", "pairs", 2**22) == pytest.approx(125.4, abs=0.05)
    assert _slope("pair", "pairs", 2**22, rows=0) == pytest.approx(117.4, abs=0.05)
    for s, per_pixel in ((1, 56.05 + 124.0), (2, 4 * 56.05 + 136.0), (4, 16 * 56.05 + 136.0)):
        slope = _slope("pixel", "height", 2**12, width=2**10, supersample=s) / 2**10
        assert slope == pytest.approx(per_pixel, abs=0.05)
    assert _slope("targets", "height", 2**12, width=2**10, views=1) / 2**10 == 12
    # past the backward's window of pairs, a pair costs its forward and tile-sort bytes only
    assert _slope("pair", "pairs", 2**22, pair_window=2**20) == pytest.approx(24.0, abs=0.05)


def test_largest_model_is_the_most_that_fits():
    args = dict(sh_degree=3, width=960, height=540, pairs_per_pixel=1.0, triangles_per_vertex=1.5)
    gib = 2**30
    n = largest_model(8 * gib, **args)
    pairs = 960 * 540
    assert training_bytes(n, round(1.5 * n), 3, 960, 540, pairs)["total"] <= 8 * gib
    assert training_bytes(n + 1, round(1.5 * (n + 1)), 3, 960, 540, pairs)["total"] > 8 * gib
    assert largest_model(16 * gib, **args) > 2 * n - 10_000        # affine: twice the memory, about twice
    # one storage binding of 128 MiB: the SH (192 bytes a vertex at degree 3) and the projected
    # triangles (96 bytes a triangle) are bound in ranges and need one 2 GiB buffer only; the
    # vertex sums (32 bytes a vertex, bound whole) come first: 2**22 vertices, under the 8 GiB
    # wall (before 2026-11-27 the SH came first: 2**27 // 192 = 699,050 vertices)
    assert n > 2**22 and largest_model(8 * gib, **args, max_binding=2**27) == 2**27 // 32
    # below that wall, a model whose projected triangles outgrow one binding also pays the two
    # gathered windows of records (2 x 518,400 pairs x 96 bytes here)
    small = largest_model(2 * gib, **args, max_binding=2**27)
    assert small < largest_model(2 * gib, **args) < 2**22 and 1.5 * small * 96 > 2**27
    assert training_bytes(small, round(1.5 * small), 3, 960, 540, pairs, pair_window=2**27 // 80,
                          max_binding=2**27)["total"] <= 2 * gib
    assert largest_model(8 * gib, **args, max_binding=2**27, max_buffer=2**27) == 2**27 // 192   # SH: one buffer
    assert largest_model(1000, **args) == 0


def test_every_buffer_of_the_trainer_is_named_once():
    names = [name for _, name, _ in training_buffers(100, 300, 3, 64, 48, 500, supersample=2, views=2)]
    assert len(names) == len(set(names))
    names = [name for _, name, _ in training_buffers(100, 300, 3, 64, 48, 500, views=2, pair_window=100)]
    assert len(names) == len(set(names)) and "pair_ids_fresh" in names


def test_a_model_over_the_available_memory_is_refused_before_its_buffers(renderer, monkeypatch):
    from tsplus_wgpu.data.procedural import load_procedural
    from tsplus_wgpu.train import memory
    from tsplus_wgpu.train.trainer import TrainConfig, Trainer
    scene = load_procedural("tiny", num_points=60)
    cfg = TrainConfig(iterations=10, quick=True, log_every=0, topology=False)
    if renderer.ctx.is_cpu:   # llvmpipe: this machine's free memory, read from /proc/meminfo
        assert memory.available_bytes(renderer.ctx) > 2**20
    monkeypatch.setattr(memory, "available_bytes", lambda ctx: 100_000)
    before = renderer.ctx.live_bytes()
    with pytest.raises(ValueError, match=r"^device memory: training [\d,]+ vertices and [\d,]+ triangles on \d+ views "
                                         r"of 64x48 needs about [\d.]+ GiB, but .* has 0.0 GiB available"):
        Trainer(scene, cfg, renderer=renderer)
    assert renderer.ctx.live_bytes() - before < 100_000          # the model's buffers were never made
    monkeypatch.setattr(memory, "available_bytes", lambda ctx: None)      # unknown (a GPU): no check
    Trainer(scene, cfg, renderer=renderer)


def test_gathered_window_records_are_counted_past_one_binding():
    """Where a model's projected triangles (96 bytes each) outgrow one storage binding, the
    forward and the backward each gather a window's records into a buffer of their own."""
    m, pairs = 3000, 5000
    plain = training_buffers(1000, m, 3, 64, 48, pairs)
    fits = training_buffers(1000, m, 3, 64, 48, pairs, max_binding=96 * m)          # exactly one binding
    assert fits == plain
    past = dict((name, b) for _, name, b in training_buffers(1000, m, 3, 64, 48, pairs, max_binding=96 * m - 16))
    assert past["forward_tris_window"] == past["backward_tris_window"] == 96 * (m - 1)   # one binding's records
    few = dict((name, b) for _, name, b in training_buffers(1000, m, 3, 64, 48, 100, max_binding=96 * 1000))
    assert few["forward_tris_window"] == 96 * 100                                   # no more than the pairs
    assert (training_bytes(1000, m, 3, 64, 48, pairs, max_binding=96 * 1000)["pair"]
            - training_bytes(1000, m, 3, 64, 48, pairs)["pair"]) == 2 * 96 * 1000
