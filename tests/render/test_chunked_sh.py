"""SH larger than one storage binding (gpu/chunks.py): the per-vertex kernels (sh_to_color,
vertex_backward) take the vertices a binding's range at a time. A model whose SH exceed the
device's real binding limit renders and backpropagates exactly as the same triangles over only
the vertices they use; the chunked kernels against their float64 twins run in
tests/kernels (train_grads, adam) and here at a small forced limit."""

import numpy as np
import pytest
from scenes import random_scene

from tsplus_wgpu import TriangleModel
import tsplus_wgpu.gpu.chunks as chunks
from tsplus_wgpu.reference.project import sh_to_color


def _spread(model, n_big, seed):
    """``model``'s vertices at scattered rows of a model of ``n_big`` vertices (the other rows
    random and unused), the last one in the last row."""
    rng = np.random.default_rng(seed)
    n, k = model.num_vertices, model.sh_size
    rows = np.sort(rng.choice(n_big - 1, n - 1, replace=False))
    rows = np.append(rows, n_big - 1)
    pos = rng.uniform(-1.0, 1.0, (n_big, 3)).astype(np.float32)
    sh = rng.normal(scale=0.3, size=(n_big, k, 3)).astype(np.float32)
    op = rng.uniform(0.3, 0.9, n_big)
    pos[rows], sh[rows], op[rows] = model.positions, model.sh, model.opacity
    return TriangleModel(pos, rows[model.triangles], sh, op), rows


def _render_both(renderer, big, small, cam):
    a, b = renderer.forward(big, cam, 0.5), renderer.forward(small, cam, 0.5)
    v = np.random.default_rng(3).normal(size=a.image.shape).astype(np.float32)
    return a, b, renderer.backward(a, v), renderer.backward(b, v)


def _same(a, b, ga, gb, rows):
    np.testing.assert_array_equal(a.image, b.image)
    np.testing.assert_array_equal(ga.v_sh[rows], gb.v_sh)
    np.testing.assert_array_equal(ga.v_positions[rows], gb.v_positions)
    np.testing.assert_array_equal(ga.v_opacity[rows], gb.v_opacity)
    unused = np.ones(len(ga.v_sh), bool)
    unused[rows] = False
    assert not np.any(ga.v_sh[unused]) and not np.any(ga.v_positions[unused])


@pytest.mark.parametrize("chunk", [2**14, 2**16])
def test_forced_small_bindings_match_whole_ones(renderer, monkeypatch, chunk):
    """At bindings of ``chunk`` bytes, the SH in many ranges: the same bits as whole bindings, and
    the colours within float32 of the twin."""
    model, cam = random_scene(11, 48, 40, sh_k=16)
    big, rows = _spread(model, 3000, 5)
    whole = _render_both(renderer, big, model, cam)
    monkeypatch.setattr(chunks, "CHUNK_BYTES", chunk)
    assert len(chunks.item_chunks(renderer.ctx, 3000, [12 * 16, 32])) >= 3
    parts = _render_both(renderer, big, model, cam)
    _same(*parts, rows)
    for w, p in zip(whole, parts):
        np.testing.assert_array_equal(*((w.image, p.image) if hasattr(w, "image") else (w.v_sh, p.v_sh)))
    colors = renderer.ctx.read(parts[0].buffers["colors"], np.float32, 4 * 3000).reshape(3000, 4)[:, :3]
    want = sh_to_color(big.positions, big.sh, cam.center)[:, :3]
    np.testing.assert_allclose(colors, want, rtol=0, atol=2e-6)


def test_sh_over_the_real_binding_limit(binding_renderer):
    """720,000 vertices at SH degree 3 (138 MB of SH, over llvmpipe's 128 MiB binding): refused
    until 2026-11-27; now the same bits as the triangles over only their own vertices."""
    renderer = binding_renderer      # bindings smaller than buffers on every adapter
    limit = min(renderer.ctx.limits["max-storage-buffer-binding-size"], renderer.ctx.limits["max-buffer-size"])
    n_big = max(720_000, limit // 192 + 1000)
    if 12 * 16 * n_big > renderer.ctx.limits["max-buffer-size"] or 32 * n_big > limit:
        pytest.skip("this adapter's buffers cannot hold the model")
    model, cam = random_scene(12, 40, 32, sh_k=16)
    big, rows = _spread(model, n_big, 6)
    assert big.sh.nbytes > limit and rows[-1] > limit // 192
    _same(*_render_both(renderer, big, model, cam), rows)


# ---------------------------------------------------------------- projected triangles past a binding


def _forward_bits(renderer, model, cam, ids=True):
    res = renderer.forward(model, cam, 0.5, triangle_ids=ids)
    c, m, h, w = renderer.ctx, model.num_triangles, cam.height, cam.width
    out = dict(image=res.image, t=res.transmittance,
               n_contrib=c.read(res.buffers["n_contrib"], np.uint32, 2 * h * w),
               max_weight=c.read(res.buffers["max_weight"], np.float32, m))
    if ids:
        out["ids"] = c.read(res.buffers["triangle_ids"], np.uint32, 2 * h * w)
    return out, res


@pytest.mark.parametrize("chunk", [2**15, 2**16])
def test_forward_in_windows_of_gathered_triangles(renderer, monkeypatch, chunk):
    """At bindings of ``chunk`` bytes the projected triangles go in pages (projection, binning)
    and the blend and ID passes in windows of pairs reading gathered records: every output the
    same bits as in one binding."""
    model, cam = random_scene(21, 96, 72, sheets=4, points_per_sheet=120, sh_k=4)
    want, res = _forward_bits(renderer, model, cam)
    monkeypatch.setattr(chunks, "CHUNK_BYTES", chunk)
    wins = renderer.tri_windows(model.num_triangles, res.num_pairs, res.max_tile_pairs)
    assert wins is not None and len(wins) >= 2 and wins[-1][1] == 0xFFFFFFFF
    assert len(chunks.item_chunks(renderer.ctx, model.num_triangles, [96])) >= 2
    got, _ = _forward_bits(renderer, model, cam)
    for key in want:
        np.testing.assert_array_equal(got[key], want[key], err_msg=key)


def test_projected_triangles_over_the_real_binding_limit(binding_renderer):
    """1,450,000 triangles (139 MB of projected records, 133 MB of corner gradients, over
    llvmpipe's 128 MiB binding): forward and backward as the visible ones alone (the others
    behind the camera, culled), bit for bit."""
    renderer = binding_renderer      # bindings smaller than buffers on every adapter
    limit = min(renderer.ctx.limits["max-storage-buffer-binding-size"], renderer.ctx.limits["max-buffer-size"])
    m_big = max(1_450_000, limit // 96 + 50_000)
    if 96 * m_big > renderer.ctx.limits["max-buffer-size"] or 16 * m_big > limit:
        pytest.skip("this adapter's buffers cannot hold the model")
    model, cam = random_scene(22, 40, 32, sh_k=1)
    n = model.num_vertices
    behind = cam.center + 3.0 * (cam.center - np.zeros(3))          # a point behind the camera
    pos = np.vstack([model.positions, behind[None]])
    hidden = np.full((m_big - model.num_triangles, 3), n)            # every corner behind: culled
    big = TriangleModel(pos, np.vstack([hidden, model.triangles]), np.vstack([model.sh, model.sh[:1]]),
                        np.append(model.opacity, 0.5))
    want, _ = _forward_bits(renderer, model, cam, ids=False)
    got, res = _forward_bits(renderer, big, cam, ids=False)
    for key in ("image", "t", "n_contrib"):
        np.testing.assert_array_equal(got[key], want[key], err_msg=key)
    np.testing.assert_array_equal(got["max_weight"][-model.num_triangles:], want["max_weight"])
    assert not np.any(got["max_weight"][:-model.num_triangles])
    v = np.random.default_rng(4).normal(size=res.image.shape).astype(np.float32)
    small = renderer.backward(renderer.forward(model, cam, 0.5), v)
    g = renderer.backward(res, v)
    for key in ("v_positions", "v_sh", "v_opacity"):
        np.testing.assert_array_equal(getattr(g, key)[:n], getattr(small, key), err_msg=key)
    assert not np.any(g.v_positions[n]) and not np.any(g.v_sh[n])


@pytest.mark.parametrize("chunk", [2**15, 2**16])
def test_backward_in_pages_of_triangles(renderer, monkeypatch, chunk):
    """At bindings of ``chunk`` bytes the backward reads gathered records per window of pairs,
    projects back a range of triangles at a time, sums the pairs' statistics into pages of
    triangles and the corners' gradients a page of corners at a time (each page adding its
    share): the gradients within 1e-5 of one binding's, which tests/render/test_backward.py
    holds to the float64 twin (only the order of the corner sums differs)."""
    model, cam = random_scene(23, 96, 72, sheets=4, points_per_sheet=120, sh_k=4)
    v = np.random.default_rng(5).normal(size=(72, 96, 3)).astype(np.float32)
    want = renderer.backward(renderer.forward(model, cam, 0.5), v)
    monkeypatch.setattr(chunks, "CHUNK_BYTES", chunk)
    m = model.num_triangles
    assert m * 80 > chunk and len(chunks.item_chunks(renderer.ctx, 3 * m, [32])) >= 2
    res = renderer.forward(model, cam, 0.5)
    got = renderer.backward(res, v)
    for key in ("v_positions", "v_sh", "v_opacity"):
        a, b = getattr(got, key), getattr(want, key)
        assert np.abs(a - b).max() <= 1e-5 * np.abs(b).max(), key
        assert np.count_nonzero(a) == np.count_nonzero(b) > 0.5 * b.size, key


def test_a_smaller_model_after_a_larger_one_reuses_the_grown_buffers(binding_renderer):
    """A scratch buffer grown past llvmpipe's 128 MiB binding by a model whose records needed
    pages (1,450,000 triangles), then a model whose records fit one: bound to its first
    binding's worth, the same bits as new buffers (the trainer's scratch after a prune). Bound
    whole, it would be over the device's binding limit."""
    renderer = binding_renderer      # bindings smaller than buffers on every adapter
    from tsplus_wgpu import Renderer
    limit = min(renderer.ctx.limits["max-storage-buffer-binding-size"], renderer.ctx.limits["max-buffer-size"])
    m_big = max(1_450_000, limit // 96 + 50_000)
    if 96 * m_big > renderer.ctx.limits["max-buffer-size"] or 16 * m_big > limit:
        pytest.skip("this adapter's buffers cannot hold the model")
    model, cam = random_scene(24, 40, 32, sh_k=1)
    hidden = np.full((m_big, 3), 0)
    big = TriangleModel(model.positions, np.vstack([hidden, model.triangles]), model.sh, model.opacity)
    own = Renderer(renderer.ctx)                   # its own scratch, dropped with it
    own.forward(big, cam, 0.5, reuse=True)
    assert own.scratch.buffers["forward_tris"].size > limit
    got = own.forward(model, cam, 0.5, reuse=True).image
    np.testing.assert_array_equal(got, renderer.forward(model, cam, 0.5).image)
