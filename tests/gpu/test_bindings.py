"""What a dispatch costs the host, made once (tsplus_wgpu/gpu/bindings.py): uniform buffers
shared by content, bind groups kept while their buffers live and dropped with them; and the
training step's forward and backward on the renderer's scratch buffers (``reuse``), which
give the same bits as new buffers."""

import gc

import numpy as np
from scenes import random_scene

from tsplus_wgpu.gpu import Scratch
from tsplus_wgpu.kernels.optim import TrainGrads


def _grads_args(ctx, n=64, k=4):
    names = ("logits", "v_sh", "v_opacity", "reg", "v_logits")
    return {name: ctx.buffer(16 * n * k, name) for name in names}


def test_uniforms_are_shared_by_content(ctx):
    k = TrainGrads(ctx)
    a = k.uniform("GradParams", n=10, k=4, active_k=1, use_reg=0, floor=0.25)
    b = k.uniform("GradParams", n=10, k=4, active_k=1, use_reg=0, floor=0.25)
    c = k.uniform("GradParams", n=11, k=4, active_k=1, use_reg=0, floor=0.25)
    assert a is b and a is not c
    ctx.host_caching = False
    try:
        assert k.uniform("GradParams", n=10, k=4, active_k=1, use_reg=0, floor=0.25) is not a
    finally:
        ctx.host_caching = True


def test_bind_groups_are_kept_while_their_buffers_live(ctx):
    k = TrainGrads(ctx)
    cache = ctx._bind_groups
    bufs = _grads_args(ctx)
    gp = k.uniform("GradParams", n=64, k=4, active_k=4, use_reg=1, floor=0.0)
    g1 = k.bind(dict(gp=gp, **bufs))
    assert k.bind(dict(gp=gp, **bufs)) is g1                  # the same buffers: the same group
    other = dict(bufs, v_logits=ctx.buffer(16 * 64 * 4, "v_logits"))
    g2 = k.bind(dict(gp=gp, **other))
    assert g2 is not g1

    def bound_ids():       # the buffers the cached groups bind (other tests' groups too)
        return {buf_id for key in cache.groups for _, buf_id, _, _ in key[1:]}

    dead_id = id(other["v_logits"])
    assert dead_id in bound_ids() and dead_id in cache.users
    del other, g2
    gc.collect()
    assert dead_id not in bound_ids() and dead_id not in cache.users     # dropped with its buffer
    assert k.bind(dict(gp=gp, **bufs)) is g1


def test_bind_groups_keep_no_more_than_their_capacity(ctx):
    from tsplus_wgpu.gpu.bindings import BindGroupCache
    k = TrainGrads(ctx)
    cache = BindGroupCache(ctx.device, capacity=3)
    bufs = _grads_args(ctx)
    entries = lambda gp: [(k.src.bindings[n].slot, b, 0, b.size) for n, b in dict(gp=gp, **bufs).items()]
    uniforms = [k.uniform("GradParams", n=i, k=4, active_k=4, use_reg=0, floor=0.0) for i in range(5)]
    groups = [cache.get(k.layout, entries(u)) for u in uniforms]
    assert len(cache) == 3 and cache.made == 5
    assert cache.get(k.layout, entries(uniforms[4])) is groups[4]          # the newest are kept
    assert cache.get(k.layout, entries(uniforms[0])) is not groups[0]      # the oldest went first
    assert all(len(keys) <= 3 for keys in cache.users.values())


def test_scratch_drops_a_buffer_before_growing_it(ctx):
    s = Scratch(ctx)
    a = s.get("x", 1000)
    assert a.size >= 1000 and s.get("x", 900) is a
    gc.collect()
    gc.disable()            # no other test's garbage freed inside the measurement
    try:
        live = ctx.live_bytes()
        a_size = a.size
        del a
        b = s.get("x", 4000, grow=1.0)
        assert b.size == 4096 and ctx.live_bytes() == live - a_size + 4096   # the old one is gone
    finally:
        gc.enable()
    assert s.get("x", 4097).size == 6144                                     # 1.5 x the old size


def test_reused_forward_and_backward_give_the_same_bits(renderer):
    """The training step's path (scratch buffers, cached bind groups) against new buffers,
    two views in turn, so the second call reuses what the first wrote."""
    rng = np.random.default_rng(5)
    scenes = [random_scene(s, 48, 40, sheets=4, points_per_sheet=14, sh_k=4) for s in (3, 4)]
    for model, cam in scenes + scenes:
        vi = rng.normal(size=(cam.height, cam.width, 3)).astype(np.float32)
        plain = renderer.forward(model, cam, 0.7)
        reused = renderer.forward(model, cam, 0.7, reuse=True)
        assert reused.reused and not plain.reused
        assert reused.buffers["image"] is renderer.scratch.get("forward_image", 1)
        assert np.array_equal(plain.image, reused.image)
        assert np.array_equal(plain.max_weight, reused.max_weight)
        ga, gb = renderer.backward(plain, vi), renderer.backward(reused, vi)
        for name in ("v_positions", "v_sh", "v_opacity"):
            assert np.array_equal(getattr(ga, name), getattr(gb, name)), name
