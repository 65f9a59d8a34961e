"""Backward pass: the float64 twin against finite differences, the WGSL backward against
the twin, finite differences through the WGSL forward, and determinism.

Scenes: 32x32, <= 20 triangles sharing vertices, sigma 1 and 0.1, chosen (by a
deterministic seed search) away from every discrete decision (no pixel within 1e-4 of
an edge, of the 1/255 skip or of the T stop; centroid depths 1e-3 apart) and, at
sigma 0.1, away from the edges where float32 cannot resolve the steep window (smallest
window ratio of a contributing pixel >= 2e-3)."""

import numpy as np
import pytest
from scenes import f32_exact, look_at_camera, random_scene

from tsplus_wgpu import TriangleModel, reference as ref
from tsplus_wgpu.reference import render_backward as rb

W = H = 32
BG = (0.1, 0.2, 0.3)
GROUPS = ("v_positions", "v_sh", "v_opacity")


def min_contrib_ratio(model, cam, sigma):
    proj = ref.projection(model, cam, sigma)
    out = np.inf
    for t in np.nonzero(proj.visible)[0]:
        x0, y0, x1, y1 = proj.rect[t]
        ys, xs = np.mgrid[y0:y1 + 1, x0:x1 + 1]
        d = np.stack([xs + 0.5 - proj.s[t, 0], ys + 0.5 - proj.s[t, 1]], -1)
        ratio = (1.0 + d @ proj.g[t].T).min(-1)
        if np.any(ratio > 0):
            out = min(out, ratio[ratio > 0].min())
    return out, proj


def smooth_scenes(sigma, count=2, sh_k=16):
    found, seed = [], 100
    while len(found) < count:
        seed += 1
        model, cam = f32_exact(*random_scene(seed, W, H, sheets=3, points_per_sheet=6, sh_k=sh_k))
        if model.num_triangles > 20:
            continue
        r = ref.render(model, cam, sigma, BG)
        mr, proj = min_contrib_ratio(model, cam, sigma)
        depths = np.sort(proj.depth[proj.visible])
        if (r.ambiguous.any() or proj.visible.sum() < 6 or (r.n_contrib > 0).sum() < 300
                or (depths.size > 1 and np.diff(depths).min() < 1e-3) or (sigma < 1 and mr < 2e-3)):
            continue
        found.append((seed, model, cam))
    return found


_CACHE = {}


def scenes_for(sigma):
    if sigma not in _CACHE:
        _CACHE[sigma] = smooth_scenes(sigma)
    return _CACHE[sigma]


def cotangents(seed):
    rng = np.random.default_rng(seed)
    return rng.normal(size=(H, W, 3)), rng.normal(size=(H, W))


def with_params(model, name, value):
    kw = dict(positions=model.positions, triangles=model.triangles, sh=model.sh, opacity=model.opacity)
    kw[{"v_positions": "positions", "v_sh": "sh", "v_opacity": "opacity"}[name]] = value
    return TriangleModel(**kw)


def param(model, name):
    return {"v_positions": model.positions, "v_sh": model.sh, "v_opacity": model.opacity}[name]


def rel(a, b):
    nb = np.linalg.norm(b)
    return np.linalg.norm(np.asarray(a, np.float64) - b) / max(nb, 1e-300)


@pytest.mark.parametrize("sigma", [1.0, 0.1])
def test_twin_backward_matches_finite_differences(sigma):
    steps = {"v_positions": 1e-7, "v_sh": 1e-6, "v_opacity": 1e-6}
    for seed, model, cam in scenes_for(sigma):
        vi, vt = cotangents(seed)
        g = rb.backward(model, cam, sigma, vi, vt, BG)
        rng = np.random.default_rng(seed)
        for name in GROUPS:
            base = param(model, name)
            grad = getattr(g, name).ravel()
            idx = np.arange(base.size)
            if name == "v_sh":   # all DC and degree-1 terms, a sample of the rest
                k = model.sh_size
                low = np.nonzero((idx // 3) % k < 4)[0]
                idx = np.union1d(low, rng.choice(base.size, 40, replace=False))
            fd = np.zeros(idx.size)
            h = steps[name]
            for n, i in enumerate(idx):
                vals = []
                for sgn in (1, -1):
                    a = base.copy().ravel()
                    a[i] += sgn * h
                    vals.append(rb.loss(with_params(model, name, a.reshape(base.shape)), cam, sigma, vi, vt, BG))
                fd[n] = (vals[0] - vals[1]) / (2 * h)
            err = np.abs(fd - grad[idx]).max() / np.abs(fd).max()
            assert np.abs(fd).max() > 0
            assert err <= 1e-5, (seed, name, err)


@pytest.mark.parametrize("sigma", [1.0, 0.1])
def test_wgsl_backward_matches_twin(renderer, sigma):
    for seed, model, cam in scenes_for(sigma):
        vi, vt = cotangents(seed)
        res = renderer.forward(model, cam, sigma, BG)
        g = renderer.backward(res, vi, vt)
        t = rb.backward(model, cam, sigma, vi, vt, BG)
        for name in GROUPS:
            e = rel(getattr(g, name), getattr(t, name))
            assert e <= 1e-4, (seed, name, e)


def gpu_loss(renderer, model, cam, sigma, vi, vt):
    res = renderer.forward(model, cam, sigma, BG)
    return float(np.sum(res.image.astype(np.float64) * vi) + np.sum(res.transmittance.astype(np.float64) * vt))


@pytest.mark.parametrize("sigma", [1.0, 0.1])
def test_finite_differences_through_wgsl_forward(renderer, sigma):
    """Directional derivatives (along the gradient and along a random direction) of the
    float32 forward on the device against the WGSL backward. The step is validated on the
    twin first (its own finite difference must match its analytic derivative, i.e. no
    discrete decision flips within the step)."""
    steps = {"v_positions": 2e-3, "v_sh": 1e-2, "v_opacity": 2e-3}
    seed, model, cam = scenes_for(sigma)[0]
    vi, vt = cotangents(seed)
    g = renderer.backward(renderer.forward(model, cam, sigma, BG), vi, vt)
    t = rb.backward(model, cam, sigma, vi, vt, BG)
    rng = np.random.default_rng(seed + 1)
    for name in GROUPS:
        base = param(model, name)
        grad = getattr(g, name).astype(np.float64)
        for kind in ("gradient", "random"):
            u = grad / np.linalg.norm(grad) if kind == "gradient" else rng.normal(size=base.shape)
            u /= np.linalg.norm(u)
            h = steps[name]
            for _ in range(4):   # shrink the step until the twin is smooth over it
                fd_twin = (rb.loss(with_params(model, name, base + h * u), cam, sigma, vi, vt, BG)
                           - rb.loss(with_params(model, name, base - h * u), cam, sigma, vi, vt, BG)) / (2 * h)
                if abs(fd_twin - np.sum(getattr(t, name) * u)) <= 1e-3 * np.linalg.norm(getattr(t, name)):
                    break
                h /= 4
            else:
                pytest.fail(f"{name}: no smooth step found")
            plus = with_params(model, name, (base + h * u).astype(np.float32))
            minus = with_params(model, name, (base - h * u).astype(np.float32))
            du = param(plus, name) - param(minus, name)   # the step float32 actually took
            fd = (gpu_loss(renderer, plus, cam, sigma, vi, vt) - gpu_loss(renderer, minus, cam, sigma, vi, vt))
            an = np.sum(grad * du)
            err = abs(fd - an) / (np.linalg.norm(grad) * np.linalg.norm(du))
            assert err <= 1e-2, (name, kind, fd, an, err)


def test_backward_is_deterministic(renderer):
    """Bit-identical gradients across runs, on a scene with many triangles per tile and
    vertices shared by many triangles."""
    model, cam = f32_exact(*random_scene(7, 96, 80, sheets=6, points_per_sheet=40, sh_k=9))
    rng = np.random.default_rng(0)
    vi, vt = rng.normal(size=(80, 96, 3)), rng.normal(size=(80, 96))
    runs = []
    for _ in range(3):
        res = renderer.forward(model, cam, 0.5, BG)
        runs.append(renderer.backward(res, vi, vt))
    for name in GROUPS:
        a = getattr(runs[0], name)
        assert np.isfinite(a).all()
        for r in runs[1:]:
            assert np.array_equal(a.view(np.uint32), getattr(r, name).view(np.uint32)), name
    t = rb.backward(model, cam, 0.5, vi, vt, BG)
    for name in ("v_sh", "v_opacity"):
        assert rel(getattr(runs[0], name), getattr(t, name)) <= 1e-3


def test_shared_vertex_gets_every_update(renderer):
    """A fan of 48 triangles around one vertex: its gradient is the sum over all of them
    (a racing += would lose most of it)."""
    n = 48
    ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
    rim = np.column_stack([1.2 * np.cos(ang), 1.2 * np.sin(ang), 0.3 * np.sin(3 * ang)])
    pos = np.vstack([[0.05, -0.03, 0.1], rim])
    tri = np.array([[0, 1 + i, 1 + (i + 1) % n] for i in range(n)])
    rng = np.random.default_rng(3)
    sh = rng.normal(scale=0.3, size=(n + 1, 4, 3))
    op = rng.uniform(0.4, 0.9, size=n + 1)
    op[0] = 0.2       # the centre holds every triangle's minimum opacity
    model, cam = f32_exact(TriangleModel(pos, tri, sh, op), look_at_camera(W, H))
    vi, vt = cotangents(5)
    g = renderer.backward(renderer.forward(model, cam, 1.0, BG), vi, vt)
    t = rb.backward(model, cam, 1.0, vi, vt, BG)
    assert abs(t.v_opacity[0]) > 0 and np.all(t.v_opacity[1:] == 0)
    assert np.all(g.v_opacity[1:] == 0)
    for name in GROUPS:
        assert rel(getattr(g, name), getattr(t, name)) <= 1e-4, name


def test_min_opacity_tie_goes_to_lowest_vertex_index(renderer):
    pos = np.array([[-1.0, -1.0, 0.0], [1.2, -0.8, 0.1], [0.0, 1.1, -0.1]])
    tri = np.array([[2, 0, 1]])
    sh = np.zeros((3, 1, 3))
    sh[:, 0] = 0.5
    model = TriangleModel(pos, tri, sh, np.array([0.7, 0.5, 0.5]))
    cam = look_at_camera(W, H)
    vi, vt = cotangents(9)
    g = renderer.backward(renderer.forward(model, cam, 1.0), vi, vt)
    t = rb.backward(model, cam, 1.0, vi, vt)
    assert t.v_opacity[1] != 0 and t.v_opacity[0] == 0 and t.v_opacity[2] == 0
    assert g.v_opacity[1] != 0 and g.v_opacity[0] == 0 and g.v_opacity[2] == 0
    assert rel(g.v_opacity, t.v_opacity) <= 1e-4


def test_backward_rejects_bad_cotangents(renderer):
    model, cam = scenes_for(1.0)[0][1:]
    res = renderer.forward(model, cam, 1.0)
    with pytest.raises(ValueError, match="v_image"):
        renderer.backward(res, np.zeros((H, W)))
    bad = np.zeros((H, W, 3))
    bad[3, 4, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        renderer.backward(res, bad)
    with pytest.raises(ValueError, match="v_transmittance"):
        renderer.backward(res, np.zeros((H, W, 3)), np.full((H, W), np.inf))
    with pytest.raises(ValueError, match="v_image"):
        rb.backward(model, cam, 1.0, np.zeros((H + 1, W, 3)))


def test_backward_in_passes_is_identical(renderer, monkeypatch):
    """rasterize_backward split into passes of a few rounds (as it is beyond 2048 pairs
    per tile, for lavapipe's loop limit) gives bit-identical gradients."""
    from tsplus_wgpu.render.backward import BackwardPass
    model, cam = f32_exact(*random_scene(8, 48, 40, sheets=5, points_per_sheet=20, sh_k=4))
    rng = np.random.default_rng(2)
    vi, vt = rng.normal(size=(40, 48, 3)), rng.normal(size=(40, 48))
    res = renderer.forward(model, cam, 0.7, BG)
    bp = BackwardPass(renderer)
    one = bp.run(res, vi, vt)
    monkeypatch.setattr(bp.raster, "rounds_per_pass", 2)
    many = bp.run(res, vi, vt)
    assert int((res.tile_ranges()[:, 1] - res.tile_ranges()[:, 0]).max()) > bp.raster.pairs_per_round * 2 * 3
    for name in GROUPS:
        assert np.array_equal(getattr(one, name), getattr(many, name)), name


@pytest.mark.parametrize("sigma", [1.0, 0.1])
def test_backward_in_pair_windows_matches_twin(renderer, sigma):
    """A view whose pairs outgrow one binding of their statistics goes window by window: with
    room for a third of the pairs (several windows, tiles straddling their borders), the
    gradients still match the twin as tightly as in one window, and the single-window path
    is unchanged, bit for bit."""
    from tsplus_wgpu.render.backward import BackwardPass, pair_windows
    bp = BackwardPass(renderer)
    for seed, model, cam in scenes_for(sigma):
        vi, vt = cotangents(seed)
        res = renderer.forward(model, cam, sigma, BG)
        one = bp.run(res, vi, vt)
        assert all(np.array_equal(getattr(one, n), getattr(renderer.backward(res, vi, vt), n)) for n in GROUPS)
        bp.pair_capacity = res.max_tile_pairs + max(1, res.num_pairs // 3)
        windows = pair_windows(res.num_pairs, res.max_tile_pairs, bp.pair_capacity)
        assert len(windows) >= 3, (res.num_pairs, res.max_tile_pairs)
        split = bp.run(res, vi, vt)
        bp.pair_capacity = None
        t = rb.backward(model, cam, sigma, vi, vt, BG)
        for name in GROUPS:
            assert rel(getattr(split, name), getattr(t, name)) <= 1e-4, (seed, name)
            assert rel(getattr(split, name), getattr(one, name)) <= 1e-5, (seed, name)


def test_backward_in_pair_windows_with_many_triangles(renderer):
    """The same on a scene of more than 16 triangles, where the pair sort takes two passes
    and leaves its result in its inputs (so each window must start from fresh pair ids)."""
    from tsplus_wgpu.render.backward import BackwardPass, pair_windows
    model, cam = f32_exact(*random_scene(8, 48, 40, sheets=5, points_per_sheet=20, sh_k=4))
    assert model.num_triangles > 16
    rng = np.random.default_rng(3)
    vi, vt = rng.normal(size=(40, 48, 3)), rng.normal(size=(40, 48))
    res = renderer.forward(model, cam, 0.7, BG)
    bp = BackwardPass(renderer)
    one = bp.run(res, vi, vt)
    bp.pair_capacity = res.max_tile_pairs + res.num_pairs // 4
    assert len(pair_windows(res.num_pairs, res.max_tile_pairs, bp.pair_capacity)) >= 4
    split = bp.run(res, vi, vt)
    for name in GROUPS:
        assert rel(getattr(split, name), getattr(one, name)) <= 1e-5, name


def test_pair_windows_cover_every_tile_once():
    """Windows start where the last one ended, hold at most the capacity (a tile starting
    just before a window's end fits), and a tile larger than the room is a clear error."""
    from tsplus_wgpu.render.backward import pair_windows
    assert pair_windows(10, 4, 10) == [(0, 10, 10)]
    assert pair_windows(0, 0, 10) == [(0, 0, 0)]
    w = pair_windows(1000, 37, 100)
    assert w[0][0] == 0 and w[-1][1] == 1000
    assert all(a[1] == b[0] for a, b in zip(w, w[1:]))
    assert all(length <= 100 and lo + length >= hi for lo, hi, length in w)
    assert all(min(1000, hi - 1 + 37) <= lo + length for lo, hi, length in w)
    with pytest.raises(ValueError, match="one 16x16 tile has 100 tile-triangle pairs"):
        pair_windows(1000, 100, 100)


def test_corner_gather_gives_the_segmented_sums_bits(renderer, monkeypatch):
    """The corner -> vertex sum per vertex (SegmentGather over the runs of the sorted corners)
    runs for host models and gives the segmented sum's gradients bit for bit."""
    from tsplus_wgpu.kernels.reduce import SegmentGather
    from tsplus_wgpu.render.backward import BackwardPass
    model, cam = f32_exact(*random_scene(9, 48, 40, sheets=3, points_per_sheet=12, sh_k=4))
    assert 3 * model.num_triangles > ref.reduce.CHUNK                 # sums over two levels
    rng = np.random.default_rng(5)
    vi, vt = rng.normal(size=(40, 48, 3)), rng.normal(size=(40, 48))
    res = renderer.forward(model, cam, 0.5, BG)
    calls = []
    real = SegmentGather.__call__
    monkeypatch.setattr(SegmentGather, "__call__", lambda self, *a, **k: calls.append(1) or real(self, *a, **k))
    got = BackwardPass(renderer).run(res, vi, vt)
    assert calls                                                          # the gather ran
    monkeypatch.setattr(SegmentGather, "fits", lambda self, n, longest: False)
    calls.clear()
    want = BackwardPass(renderer).run(res, vi, vt)                        # the segmented sum
    assert not calls
    for name in GROUPS:
        assert np.array_equal(getattr(got, name), getattr(want, name)), name
    assert np.any(got.v_positions != 0)


def test_corner_order_cache_follows_topology(renderer):
    """The corner order (sorted by vertex) is kept per topology for host models: the same
    model again, and then another topology with as many vertices and triangles, give
    exactly the gradients of a backward pass without the cache."""
    from tsplus_wgpu.render.backward import BackwardPass
    model, cam = f32_exact(*random_scene(9, 48, 40, sheets=3, points_per_sheet=12, sh_k=4))
    rng = np.random.default_rng(3)
    vi, vt = rng.normal(size=(40, 48, 3)), rng.normal(size=(40, 48))
    tri = model.triangles.copy()
    other = TriangleModel(model.positions, tri[::-1, [1, 2, 0]].copy(), model.sh, model.opacity)
    cached = BackwardPass(renderer)
    for m in (model, model, other, model):
        res = renderer.forward(m, cam, 0.5, BG)
        got = cached.run(res, vi, vt)
        want = BackwardPass(renderer).run(res, vi, vt)
        for name in GROUPS:
            assert np.array_equal(getattr(got, name), getattr(want, name)), name
