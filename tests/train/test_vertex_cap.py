"""The densification cap (train/strategy/cap.py): the smallest of --max-vertices, the vertex budget
(F x the mean training pixels) and what one storage binding holds; densification never passes it,
and the pause at the cap and log.jsonl name the bound."""

import math
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from tsplus_wgpu.gpu.context import WEBGPU_DEFAULT_LIMITS
from tsplus_wgpu.train.config import TrainConfig
from tsplus_wgpu.train.schedules import Schedule
from tsplus_wgpu.train.state import VertexState
from tsplus_wgpu.train.strategy import TopologyStrategy, VertexCap, vertex_cap
from tsplus_wgpu.train.strategy.cap import triangle_bytes


def _cams(*sizes):
    return [SimpleNamespace(width=w, height=h) for w, h in sizes]


LUND = _cams((237, 178)) * 3          # lund at --downscale 4: 42,186 pixels per training image


def test_the_cap_is_the_vertex_budget_times_the_mean_training_pixels():
    cap = vertex_cap(TrainConfig(), LUND)
    assert cap.vertices == math.ceil(2.0 * 237 * 178) == 84_372 and cap.bound == "vertex budget"
    assert cap.reached(84_372) == "vertex budget reached (84,372 >= 2.0 x 42,186 training pixels)"
    assert "under --max-vertices 3,000,000" in cap.why and cap.triangles is None    # no device: no binding bound
    mixed = vertex_cap(TrainConfig(vertex_budget=1.5), _cams((100, 100), (200, 100), (300, 100)))
    assert mixed.vertices == 30_000 and mixed.inputs["training_pixels"] == 20_000      # the mean image
    assert vertex_cap(TrainConfig(vertex_budget=0.3), _cams((7, 1))).vertices == 3    # rounded up


def test_max_vertices_applies_when_smaller_or_without_a_budget():
    cap = vertex_cap(TrainConfig(max_vertices=50_000), LUND)
    assert (cap.vertices, cap.bound) == (50_000, "max-vertices")
    assert cap.reached(50_000) == "max-vertices reached (50,000 >= 50,000)"
    assert "under the vertex budget 2.0 x 42,186" in cap.why
    off = vertex_cap(TrainConfig(vertex_budget=0), LUND)
    assert (off.vertices, off.bound, off.why) == (3_000_000, "max-vertices", "--max-vertices; no vertex budget")


def test_the_device_limits_lower_the_cap():
    # the paper's images (1.6k x 1k): the budget allows 3.2M, --max-vertices 3M. The SH are bound a
    # range of vertices at a time: one WebGPU-default 256 MiB buffer holds the SH (16 x 12 bytes)
    # of 1,398,101 vertices (one 128 MiB binding held 699,050 before they were chunked)
    cap = vertex_cap(TrainConfig(), _cams((1600, 1000)), WEBGPU_DEFAULT_LIMITS)
    assert (cap.vertices, cap.bound) == (2**28 // 192, "buffer-size limit") == (1_398_101, "buffer-size limit")
    assert "--max-vertices allows 3,000,000 vertices" in cap.why and "over this device's 256 MiB buffer" in cap.why
    assert cap.reached(1_398_101).startswith("buffer-size limit reached (1,398,101 >= 1,398,101, the most vertices")
    # the triangles: 16 bytes each bound whole (pixel boxes), 96 in ranges (one 256 MiB buffer)
    assert cap.triangles == min(2**27 // 16, 2**28 // triangle_bytes()) == 2**28 // 96 and triangle_bytes() == 96
    # llvmpipe's 2 GiB buffers: the SH of 11.2 M vertices fit; 3M is the cap
    lavapipe = dict(WEBGPU_DEFAULT_LIMITS, **{"max-buffer-size": 2**31 - 256})
    assert vertex_cap(TrainConfig(), _cams((1600, 1000)), lavapipe).bound == "max-vertices"
    # the vertex sums (32 bytes a vertex) bound whole: one binding of them
    sums = dict(lavapipe, **{"max-storage-buffer-binding-size": 32 * 1000})
    cap = vertex_cap(TrainConfig(), LUND, sums)
    assert (cap.vertices, cap.bound, cap.triangles) == (1000, "storage-binding limit", 32_000 // 16)
    assert "the vertex budget allows 84,372" in cap.why and "vertex sums" in cap.why
    small = dict(WEBGPU_DEFAULT_LIMITS, **{"max-buffer-size": 192 * 1000})
    cap = vertex_cap(TrainConfig(), LUND, small)
    assert (cap.vertices, cap.triangles) == (1000, 2000) and "the vertex budget allows 84,372" in cap.why   # buffer // 96
    # 12 bytes of SH a vertex fit 16,000 in the buffer; the sums' binding (192,000 bytes) holds 6,000
    assert vertex_cap(TrainConfig(sh_degree=0), LUND, small).vertices == 192_000 // 32
    assert vertex_cap(TrainConfig(), LUND, WEBGPU_DEFAULT_LIMITS).bound == "vertex budget"     # fits: unchanged


def _grid(side, k=16):
    """A flat ``side`` x ``side`` vertex grid, every triangle at max weight 1: a state densify can split."""
    y, x = np.mgrid[:side, :side]
    pos = np.column_stack([x.ravel(), y.ravel(), np.zeros(side * side)]).astype(np.float64) * 0.05
    i = (y[:-1, :-1] * side + x[:-1, :-1]).ravel()
    tris = np.concatenate([np.column_stack([i, i + 1, i + side]), np.column_stack([i + 1, i + side + 1, i + side])])
    state = VertexState.from_model(pos, tris, np.zeros((side * side, k, 3)), np.zeros(side * side))
    return replace(state, max_weight=np.ones(len(tris), np.float32))


@pytest.mark.parametrize("cap", [VertexCap(520, "vertex budget", "2.0 x 260 training pixels"),
                                 VertexCap(10_000, triangles=980)])
def test_densification_never_passes_the_cap(ctx, cap):
    s = TopologyStrategy(Schedule(total=30000), max_vertices=cap, stop_rel=0.0)
    assert s.max_vertices == cap.vertices and s.events == [cap.record()]      # the cap, logged first
    state = _grid(20)                                                          # 400 vertices, 722 triangles
    s.attach(ctx, state.m)
    for it in range(1000, 4000, 500):                       # the paper's densify steps before the first prune
        state = s.edit(state, it, [], [])
        assert state.n <= cap.vertices and (cap.triangles is None or state.m <= cap.triangles)
        state = replace(state, max_weight=np.ones(state.m, np.float32))
    assert state.n > 400
    if cap.triangles is None:                # splits add 1 to 3 vertices: the model may end just under the cap
        assert state.n >= cap.vertices - 2
        assert s.check_stop(4000, cap.vertices) is False
        assert s.at_cap == "vertex budget reached (520 >= 2.0 x 260 training pixels)"
    else:                                    # no room for 3 more triangles
        assert s.at_cap.startswith("storage-binding limit reached (980 triangles: a split would pass 980")
    assert s.densify_stopped is None         # the cap pauses, it does not stop
    paused = [e for e in s.events if e["event"] == "densify_paused"]
    assert len(paused) == 1 and paused[0]["reason"] == s.at_cap
    assert not [e for e in s.events if e["event"] == "densify_stop"]
    # a prune that frees room lets the next densify step grow the model again, to the cap
    small = _grid(12)                                                          # 144 vertices, 242 triangles
    grown = s.edit(small, 4000, [], [])
    assert grown.n > small.n and grown.n <= cap.vertices and s.at_cap is None
    assert s.events[-2]["event"] == "densify_resumed" and s.events[-2]["iteration"] == 4000


def test_a_plain_number_is_still_a_max_vertices_cap():
    s = TopologyStrategy(Schedule(total=30000), max_vertices=100)
    assert (s.max_vertices, s.cap.bound) == (100, "max-vertices")
    s.check_stop(1000, 100, 10**9)
    assert s.at_cap == "max-vertices reached (100 >= 100)" and s.densify_stopped is None
    assert TopologyStrategy(Schedule(total=30000), enabled=False).events == []    # topology off: nothing to log


def test_the_trainer_caps_its_scene_and_device(renderer, monkeypatch):
    """procedural:tiny (64x48 = 3,072 pixels): the budget gives 6,144 vertices; in the real loop a
    budget just above the initial model stops densification there; a storage binding shrunk to
    what the initial model's largest buffer needs (48 bytes a triangle: the opacity loss's corners)
    holds the SH of fewer vertices than the budget allows, and lowers the cap."""
    from tsplus_wgpu.data import load_procedural
    from tsplus_wgpu.train.trainer import Trainer
    tiny = load_procedural("tiny")
    scaled = dict(iterations=300, quick=True, seed=1, quick_topology_epochs=0, quick_opacity_lr_scale=1)
    t = Trainer(tiny, TrainConfig(**scaled), renderer=renderer)
    assert (t.topology.cap.vertices, t.topology.cap.bound) == (6144, "vertex budget")
    assert t.topology.events[0]["event"] == "vertex_cap" and t.topology.events[0]["training_pixels"] == 3072
    n0, m0 = t.n, t.m
    t = Trainer(tiny, TrainConfig(vertex_budget=(n0 + 200) / 3072, **scaled), renderer=renderer)
    cap = t.topology.cap.vertices
    assert n0 + 200 <= cap <= n0 + 201
    while t.iteration < 40:               # densify steps at 10, 20, 30 (the scaled 500-iteration interval)
        t.step()
        assert t.n <= cap
    assert t.n > n0
    limit = (48 * m0 + 15) // 16 * 16
    assert limit // 192 < 6144
    monkeypatch.setitem(renderer.ctx.limits, "max-buffer-size", limit)     # the SH: one buffer, in ranges
    cap = Trainer(tiny, TrainConfig(**scaled), renderer=renderer).topology.cap
    assert (cap.vertices, cap.bound, cap.triangles) == (limit // 192, "buffer-size limit", limit // 96)
    assert "the vertex budget allows 6,144 vertices" in cap.why
