"""shaders/blend/: rasterize_forward and its TRIANGLE_IDS variant (the triangle-ID pass, host
class RasterizeIds), each alone on sorted pairs and tile ranges that the twins build from the
projection kernel's own records, against their float64 twins; then the ID pass end to end
(``Renderer.forward(..., triangle_ids=True)``): integer IDs exactly, except pixels where the
twin's two largest weights are within float32 reach of each other or a discrete decision is
within rounding of flipping (the twin's ``ambiguous``)."""

import numpy as np
import pytest
from scenes import f32_exact, look_at_camera, random_scene, submit as _run

from tsplus_wgpu import TriangleModel, reference
from tsplus_wgpu.kernels.blend import (RasterizeForward, RasterizeForwardGpu, RasterizeIds, RasterizeIdsGpu,
                                       forward_stage)

CASES = [((17, 33), 1.0), ((256, 192), 0.5), ((96, 64), 0.1), ((64, 48), 1e-4)]
BG = (0.2, 0.3, 0.4)


def blend_inputs(renderer, model, cam, sigma):
    """The forward of ``model`` (its Tri2D records come from the projection kernel) and the
    blend's inputs built by the twins from those records: depth order, sorted pairs
    ``pair_tris [P]``, tile ranges ``[tiles, 2]`` and the records as a twin ``Projection``."""
    res = renderer.forward(model, cam, sigma, background=BG)
    rec, rects = res.projected()
    order = res.depth_order()
    g = np.stack([rec["g0"], rec["g1"], rec["g2"]], 1)
    pair_tiles, pair_tris = reference.bin_pairs(rec["s"], g, rec["tau"], rects, order, cam.width, cam.height)
    ranges = reference.tile_ranges(pair_tiles, renderer.tiles(cam)[2])
    return res, order, pair_tris, ranges, reference.projection_from_records(rec, rects)


def run_blend(renderer, stage, res, cam, sigma, pair_tris, ranges, outputs):
    """Record ``stage`` alone on uploaded pairs and ranges (and the forward's Tri2D records);
    returns the device buffers of ``outputs`` {name: bytes per pixel or per triangle}."""
    c = renderer.ctx
    tx, ty, _ = renderer.tiles(cam)
    params = renderer.frame_params(res.model, cam, sigma, BG, 0.01, len(pair_tris))
    bufs = {k: c.buffer(n) for k, n in outputs.items()}
    max_tile_pairs = int((ranges[:, 1].astype(np.int64) - ranges[:, 0]).max())
    enc = c.device.create_command_encoder()
    stage(enc, params, c.upload(ranges.astype(np.uint32)), c.upload(np.asarray(pair_tris, np.uint32)),
          res.buffers["tris"], *bufs.values(), tx, ty, max_tile_pairs)
    c.queue.submit([enc.finish()])
    return bufs


def forward_alone(renderer, res, cam, sigma, pair_tris, ranges, stage=None):
    """RasterizeForward alone: (image, T, (last, evaluated), max_weight, work) as numpy."""
    c, h, w, m = renderer.ctx, cam.height, cam.width, res.model.num_triangles
    b = run_blend(renderer, stage or renderer.blend, res, cam, sigma, pair_tris, ranges,
                  dict(image=12 * h * w, final_t=4 * h * w, n_contrib=8 * h * w, max_weight=4 * m, work=16))
    return (c.read(b["image"], np.float32, 3 * h * w).reshape(h, w, 3), c.read(b["final_t"], np.float32, h * w).reshape(h, w),
            c.read(b["n_contrib"], np.uint32, 2 * h * w).reshape(h, w, 2), c.read(b["max_weight"], np.float32, m),
            c.read(b["work"], np.uint32, 2))


def ids_alone(renderer, res, cam, sigma, pair_tris, ranges, stage=None):
    """RasterizeIds alone: (ids [H, W] int32, weights [H, W] float32, T [H, W])."""
    c, h, w = renderer.ctx, cam.height, cam.width
    b = run_blend(renderer, stage or forward_stage(c, triangle_ids=True), res, cam, sigma, pair_tris, ranges,
                  dict(id_t=4 * h * w, id_state=8 * h * w))
    state = c.read(b["id_state"], np.uint32, 2 * h * w).reshape(h, w, 2)
    return (state[..., 0].astype(np.int32), np.ascontiguousarray(state[..., 1]).view(np.float32),
            c.read(b["id_t"], np.float32, h * w).reshape(h, w))


def small_passes(cls, pairs):
    """``cls`` blending ``pairs`` pairs per tile and dispatch: the state carried between passes."""
    class Small(cls):
        def const(self, name):
            return pairs if name == "PASS_PAIRS" else super().const(name)
    return Small


@pytest.mark.parametrize("size,sigma", CASES, ids=[f"{w}x{h}-{s}" for (w, h), s in CASES])
def test_rasterize_forward(layout_renderers, size, sigma):
    check_forward(layout_renderers["cpu"], RasterizeForward, size, sigma)


@pytest.mark.parametrize("size,sigma", CASES, ids=[f"{w}x{h}-{s}" for (w, h), s in CASES])
def test_rasterize_forward_gpu(layout_renderers, size, sigma):
    """The GPU layout (one invocation a pixel): the same checks, and the same integer outputs
    as the CPU layout's, its floats within rounding of them."""
    image, final_t, state, max_weight, work = check_forward(layout_renderers["gpu"], RasterizeForwardGpu, size, sigma)
    other = check_forward(layout_renderers["cpu"], RasterizeForward, size, sigma)
    np.testing.assert_array_equal(state, other[2])
    np.testing.assert_array_equal(work, other[4])
    np.testing.assert_allclose(image, other[0], rtol=0, atol=2e-6)
    np.testing.assert_allclose(final_t, other[1], rtol=0, atol=2e-6)
    np.testing.assert_allclose(max_weight, other[3], rtol=0, atol=2e-6)


def check_forward(renderer, cls, size, sigma):
    """The blend of ``cls`` (``renderer``'s own layout) alone against the twin, inside the
    renderer, and in passes of 7 pairs; returns its outputs."""
    assert type(renderer.blend) is cls
    model, cam = f32_exact(*random_scene(21 + size[0], *size, sheets=6, points_per_sheet=30, sh_k=4))
    res, order, pair_tris, ranges, proj = blend_inputs(renderer, model, cam, sigma)
    image, final_t, state, max_weight, work = forward_alone(renderer, res, cam, sigma, pair_tris, ranges)
    ref = reference.rasterize_forward(proj, order, cam.width, cam.height, sigma, BG)
    ok = ~ref.ambiguous
    assert ok.mean() > 0.99
    err = np.abs(image - ref.image).max(axis=-1)
    assert err[ok].max() <= 1e-5, err[ok].max()
    assert np.abs(final_t - ref.transmittance)[ok].max() <= 3e-5     # a product over up to ~12 layers
    np.testing.assert_allclose(max_weight, ref.max_weight, atol=1e-4)   # its pixel may be an ambiguous one
    last, evaluated = state[..., 0], state[..., 1]
    assert np.all(last[ok] >= ref.n_contrib[ok])        # the last contributing pair covers the twin's count
    assert np.all(evaluated >= last) and np.all(evaluated >> 31 == 0)   # no "stopped" flag after the last pass
    assert abs(int(work[1]) - int(ref.n_contrib.sum())) <= int(ref.ambiguous.sum())
    assert work[0] >= work[1]
    # alone on the twins' pairs, bit for bit what it gives inside the renderer
    np.testing.assert_array_equal(image, res.image)
    np.testing.assert_array_equal(final_t, res.transmittance)
    np.testing.assert_array_equal(last, res.n_contrib)
    np.testing.assert_array_equal(max_weight, res.max_weight)
    # in passes of 7 pairs per tile (the pixel state carried in the outputs): bit for bit the same
    small = small_passes(cls, 7)(renderer.ctx)
    if size[0] >= 64:
        assert int((ranges[:, 1].astype(np.int64) - ranges[:, 0]).max()) > 14    # three passes or more
    again = forward_alone(renderer, res, cam, sigma, pair_tris, ranges, small)
    for a, b in zip(again, (image, final_t, state, max_weight, work)):
        np.testing.assert_array_equal(a, b)
    return image, final_t, state, max_weight, work


@pytest.mark.parametrize("size,sigma", CASES, ids=[f"{w}x{h}-{s}" for (w, h), s in CASES])
def test_rasterize_ids(layout_renderers, size, sigma):
    check_ids(layout_renderers["cpu"], RasterizeIds, size, sigma)


@pytest.mark.parametrize("size,sigma", CASES, ids=[f"{w}x{h}-{s}" for (w, h), s in CASES])
def test_rasterize_ids_gpu_layout(layout_renderers, size, sigma):
    """The ID pass in the GPU layout: the same checks, the same IDs as the CPU layout's."""
    ids, weights, id_t = check_ids(layout_renderers["gpu"], RasterizeIdsGpu, size, sigma)
    other = check_ids(layout_renderers["cpu"], RasterizeIds, size, sigma)
    np.testing.assert_array_equal(ids, other[0])
    np.testing.assert_allclose(weights, other[1], rtol=0, atol=2e-6)


def check_ids(renderer, cls, size, sigma):
    model, cam = f32_exact(*random_scene(31 + size[0], *size, sheets=6, points_per_sheet=30, sh_k=4))
    res, order, pair_tris, ranges, proj = blend_inputs(renderer, model, cam, sigma)
    ids, weights, id_t = ids_alone(renderer, res, cam, sigma, pair_tris, ranges, cls(renderer.ctx))
    ref = reference.rasterize_ids(proj, order, cam.width, cam.height, sigma=sigma)
    drawn = ref.weight > 0
    ok = ~ref.ambiguous & ~(drawn & (ref.weight - ref.second <= 1e-4 * ref.weight + 1e-7))
    bad = np.argwhere(ok & (ids != ref.ids))
    assert len(bad) == 0, f"{len(bad)} pixels differ, first {bad[:5].tolist()}"
    assert (~ok & drawn).sum() <= max(2, 0.05 * drawn.sum())
    np.testing.assert_allclose(weights[ok], ref.weight[ok], rtol=2e-3, atol=1e-6)
    # the same walk as the forward blend: its T bit for bit, -1 exactly where T stays 1
    np.testing.assert_array_equal(id_t, res.transmittance)
    np.testing.assert_array_equal(ids < 0, id_t == 1.0)
    # in passes of 7 pairs per tile: bit for bit the same
    again = ids_alone(renderer, res, cam, sigma, pair_tris, ranges, small_passes(cls, 7)(renderer.ctx))
    for a, b in zip(again, (ids, weights, id_t)):
        np.testing.assert_array_equal(a, b)
    return ids, weights, id_t


# ---- the ID pass end to end (Renderer.forward(..., triangle_ids=True))

def _compare(res, ref, max_excluded=0.02):
    ids = res.triangle_ids
    assert ids.dtype == np.int32 and ids.shape == ref.ids.shape
    drawn = ref.weight > 0
    close = drawn & (ref.weight - ref.second <= 1e-4 * ref.weight + 1e-7)
    ok = ~ref.ambiguous & ~close
    bad = np.argwhere(ok & (ids != ref.ids))
    assert len(bad) == 0, f"{len(bad)} pixels differ, first {bad[:5].tolist()}: got {ids[tuple(bad[0])]}, " \
                          f"twin {ref.ids[tuple(bad[0])]}"
    # what is left out is a thin band of edge pixels, not the image
    assert (~ok & drawn).sum() <= max(2, max_excluded * drawn.sum())
    # -1 exactly where nothing contributed (T stays 1)
    np.testing.assert_array_equal(ids < 0, res.transmittance == 1.0)
    w = res.triangle_id_weights
    np.testing.assert_allclose(w[ok], ref.weight[ok], rtol=2e-3, atol=1e-6)
    return ok


@pytest.mark.parametrize("size", [(1, 1), (17, 33), (256, 192)])
@pytest.mark.parametrize("sigma", [1.0, 0.1, 1e-4])
def test_ids_match_twin(renderer, size, sigma):
    w, h = size
    model, cam = f32_exact(*random_scene(7 + w, w, h, sheets=4, points_per_sheet=10, sh_k=4))
    res = renderer.forward(model, cam, sigma, triangle_ids=True)
    ref = reference.triangle_ids(model, cam, sigma)
    _compare(res, ref, max_excluded=0.05 if w > 1 else 1.0)
    if w > 100:
        assert len(np.unique(ref.ids)) > 20      # many triangles win somewhere


def test_ids_not_computed_unless_asked(renderer):
    from tsplus_wgpu import Renderer
    r = Renderer(renderer.ctx)
    model, cam = f32_exact(*random_scene(3, 32, 24))
    res = r.forward(model, cam, 0.5)
    assert r._ids is None                    # the ID pipeline is not even compiled
    assert "triangle_ids" not in res.buffers
    with pytest.raises(ValueError, match="triangle_ids=True"):
        res.triangle_ids
    # asking for IDs leaves the image as it was
    res2 = r.forward(model, cam, 0.5, triangle_ids=True)
    np.testing.assert_array_equal(res2.image, res.image)


def _quad_pair(opacities, dz=(0.0, 0.0)):
    """Two copies of one screen-covering triangle at depths dz."""
    tri = np.array([[-6, 4, 0], [6, 4, 0], [0, -8, 0]], float)
    pos = np.concatenate([tri + [0, 0, dz[0]], tri + [0, 0, dz[1]]])
    op = np.repeat(np.asarray(opacities, float), 3)
    return TriangleModel(pos, np.arange(6).reshape(2, 3), np.zeros((6, 1, 3)), op)


def test_largest_weight_wins_not_the_front(renderer):
    cam = look_at_camera(20, 20)
    # front 0.3 (weight 0.3) vs behind 0.9 (weight 0.7 * 0.9 = 0.63): the one behind wins
    ids = renderer.forward(_quad_pair([0.3, 0.9], dz=(0.0, 0.5)), cam, 1e-4, triangle_ids=True).triangle_ids
    assert np.all(ids == 1)
    ids = renderer.forward(_quad_pair([0.6, 0.9], dz=(0.0, 0.5)), cam, 1e-4, triangle_ids=True).triangle_ids
    assert np.all(ids == 0)                  # 0.6 > 0.4 * 0.9


def test_near_ties_are_deterministic(renderer):
    """Exact float32 ties cannot be built through the window (alpha = o I(p)); the rule (the
    weight must grow strictly, so the front-most of equal weights stays) is exercised by
    near-ties: the same answer on every run, and the twin's on every pixel it can decide."""
    cam = look_at_camera(20, 20)
    model = _quad_pair([0.25, 1.0 / 3.0], dz=(0.0, 0.0))
    f32 = TriangleModel(model.positions, model.triangles, model.sh,
                        model.opacity.astype(np.float32).astype(np.float64))
    runs = [renderer.forward(f32, cam, 1e-4, triangle_ids=True).triangle_ids for _ in range(3)]
    assert all(np.array_equal(runs[0], r) for r in runs[1:])
    ref = reference.triangle_ids(f32, cam, 1e-4)
    assert np.all(np.abs(ref.weight - ref.second) < 1e-4)   # weights 0.25 I and (1 - 0.25 I) I / 3


def test_renderer_triangle_ids_draws_opaque(renderer):
    model, cam = f32_exact(*random_scene(5, 48, 40, opacity=(0.1, 0.3)))
    got = renderer.triangle_ids(model, cam)
    opaque = TriangleModel(model.positions, model.triangles, model.sh[:, :1], np.ones(model.num_vertices))
    ref = reference.triangle_ids(opaque, cam, 1e-4)
    ok = ~ref.ambiguous & ((ref.weight == 0) | (ref.weight - ref.second > 1e-4))
    np.testing.assert_array_equal(got[ok], ref.ids[ok])
    # opaque: the winner is the first triangle drawn at the pixel (weight 0.99)
    assert np.allclose(ref.weight[ref.weight > 0], 0.99)


def _layers(tri, k, dz, opacity):
    pos = np.concatenate([tri + [0, 0, dz * i] for i in range(k)])
    return pos, np.arange(3 * k).reshape(k, 3), np.full(3 * k, opacity)


def test_ids_across_several_passes(renderer):
    """A tile with more pairs than one pass (32768): the state carries between dispatches.
    40,000 faint triangles on pixel (3, 3) first, then 50 tile-covering ones behind them,
    reached by every other pixel in the second pass."""
    cam = look_at_camera(16, 16)
    s = 4 / cam.fx
    c = (np.array([3.5, 3.5]) - 8) * s
    tiny = np.array([[c[0] - 1.5 * s, c[1] + 1.5 * s, 0], [c[0] + 1.5 * s, c[1] + 1.5 * s, 0],
                     [c[0], c[1] - 1.5 * s, 0]])
    big = np.array([[-6, 4, 0], [6, 4, 0], [0, -8, 0]], float)
    p1, t1, o1 = _layers(tiny, 40_000, 1e-5, 0.004)
    p2, t2, o2 = _layers(big + [0, 0, 1.0], 50, 1e-3, 0.1)
    model = TriangleModel(np.concatenate([p1, p2]), np.concatenate([t1, t2 + len(p1)]),
                          np.zeros((len(p1) + len(p2), 1, 3)), np.concatenate([o1, o2]))
    res = renderer.forward(model, cam, 1e-4, triangle_ids=True)
    assert res.max_tile_pairs > 32768
    ids = res.triangle_ids
    assert ids[3, 3] == 0                    # the front-most faint one (weights only shrink behind it)
    others = np.ones((16, 16), bool)
    others[2:5, 2:5] = False
    covered = others & (res.transmittance < 1.0)
    assert covered.sum() > 200
    assert np.all(ids[covered] == 40_000)    # the front-most big one: weight 0.1, the rest less
    assert np.all(ids[others & ~covered] == -1)


def test_poisoned_buffers_give_the_same_ids(renderer):
    """Every new buffer filled with 0xFF: the ID pass relies on no zero-initialised memory."""
    from tsplus_wgpu import Renderer
    from tsplus_wgpu.gpu import GpuContext
    model, cam = f32_exact(*random_scene(9, 70, 50, sheets=4, points_per_sheet=10))
    clean = renderer.forward(model, cam, 0.3, triangle_ids=True)
    poisoned = Renderer(GpuContext(renderer.ctx.adapter, poison=True)).forward(model, cam, 0.3, triangle_ids=True)
    np.testing.assert_array_equal(poisoned.triangle_ids, clean.triangle_ids)
    np.testing.assert_array_equal(poisoned.triangle_id_weights, clean.triangle_id_weights)


@pytest.mark.parametrize("m,lo,count,chunk", [(1, 0, 5, None), (1000, 0, 3000, None), (1000, 777, 2500, 2**13),
                                              (5000, 123, 4000, 2**14)])
def test_gather_tris(ctx, monkeypatch, m, lo, count, chunk):
    """The window's records in pair order against the twin, bit for bit; with ``chunk`` the
    records are read a page of triangles at a time (one dispatch a page)."""
    import tsplus_wgpu.gpu.chunks as chunks
    from tsplus_wgpu.kernels.blend import GatherTris
    monkeypatch.setattr(chunks, "CHUNK_BYTES", chunk)
    stage = GatherTris(ctx)
    size = stage.src.structs["Tri2D"].itemsize                      # 96 bytes, moved as they are
    rng = np.random.default_rng(m + count)
    records = rng.normal(size=(m, size // 4)).astype(np.float32).view(np.uint32)   # finite floats
    pair_tris = rng.integers(0, m, lo + count + 7).astype(np.uint32)
    if chunk:
        assert len(chunks.item_chunks(ctx, m, [size])) >= 3
    out = ctx.buffer(size * count, "gathered")
    _run(ctx, lambda enc: stage(enc, ctx.upload(pair_tris), ctx.upload(records, chunked=True), out, lo, count, m,
                                size))
    got = ctx.read(out, np.uint32, count * size // 4).reshape(count, size // 4)
    np.testing.assert_array_equal(got, reference.gather_tris(records, pair_tris, lo, count))
