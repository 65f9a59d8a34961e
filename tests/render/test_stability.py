"""Numerical stability: hard cases give finite images and gradients and agree with the
float64 twin.

Agreement: the image within the twin's float32 error model (``1e-5 + 2 f32_bound``) on
pixels where no discrete decision is within rounding of flipping (``ambiguous``); the
gradients per group (relative L2 error), with the incoming gradient set to zero on the
ambiguous pixels (there float32 may legitimately take the other branch, and the
per-pixel gradients are independent, so masking removes exactly those pixels). The
tolerance is 1e-4 unless a case is ill-conditioned in float32 by construction (said
where it is used)."""

import time

import numpy as np
import pytest
from scenes import f32_exact, look_at_camera, random_scene

from tsplus_wgpu import Camera, TriangleModel, reference as ref
from tsplus_wgpu.reference import render_backward as rb

GROUPS = ("v_positions", "v_sh", "v_opacity")


def eye_camera(w=32, h=32, f=32.0, cx=None, cy=None):
    """Camera at the origin looking down +z: u = f x / z + cx, v = f y / z + cy."""
    return Camera(w, h, f, f, w / 2 if cx is None else cx, h / 2 if cy is None else cy, np.eye(4))


def model_of(pos, tri, seed=0, k=4, opacity=None):
    rng = np.random.default_rng(seed)
    pos = np.asarray(pos, np.float64)
    n = pos.shape[0]
    sh = rng.normal(scale=0.3, size=(n, k, 3))
    sh[:, 0] = rng.uniform(-1, 1, size=(n, 3))
    op = rng.uniform(0.3, 0.9, size=n) if opacity is None else np.broadcast_to(opacity, (n,)).astype(float)
    return TriangleModel(pos, np.asarray(tri), sh, op)


def rel(a, b):
    nb = np.linalg.norm(b)
    return np.linalg.norm(np.asarray(a, np.float64) - b) / max(nb, 1e-300)


def check(renderer, model, cam, sigma, tol=1e-4, bg=(0.1, 0.2, 0.3), seed=0, twin=True, near=0.01):
    """Forward + backward on the device and in the twin; returns (result, grads, errors)."""
    model, cam = f32_exact(model, cam)
    res = renderer.forward(model, cam, sigma, bg, near=near)
    img, T = res.image, res.transmittance
    assert np.isfinite(img).all() and np.isfinite(T).all()
    rng = np.random.default_rng(seed)
    vi = rng.normal(size=img.shape)
    vt = rng.normal(size=T.shape)
    if twin:
        r = ref.render(model, cam, sigma, bg, near)
        ok = ~r.ambiguous
        err = np.abs(img - r.image).max(axis=-1)
        assert (err - 1e-5 - 2 * r.f32_bound)[ok].max(initial=0) <= 0
        vi[~ok] = 0
        vt[~ok] = 0
    g = renderer.backward(res, vi, vt)
    for name in GROUPS:
        assert np.isfinite(getattr(g, name)).all(), name
    errs = {}
    if twin:
        t = rb.backward(model, cam, sigma, vi, vt, bg, near)
        for name in GROUPS:
            a, b = getattr(g, name), getattr(t, name)
            assert np.isfinite(b).all()
            if not np.any(b):
                assert not np.any(a), name
                errs[name] = 0.0
            else:
                errs[name] = rel(a, b)
        bad = {k: v for k, v in errs.items() if v > tol}
        assert not bad, bad
    print("[stability]", "sigma", sigma, {k: "%.2e" % v for k, v in errs.items()})
    return res, g, errs


def test_zero_area_collinear_and_sliver(renderer):
    # camera at the origin, z = 2: one world unit = 16 px
    pos = [[-0.5, -0.5, 2.0], [0.6, -0.4, 2.1], [0.0, 0.7, 1.9],      # a normal triangle
           [0.2, 0.2, 2.0], [0.5, 0.5, 2.0],                           # zero area: (0, 3, 3), collinear (3, 4, 5)
           [0.8, 0.8, 2.0],
           [-0.9, 0.1, 2.0], [0.9, 0.1, 2.0], [0.0, 0.1 + 2.5e-7, 2.0],  # sliver, inradius ~1e-6 px
           [0.0, 0.1 + 2.5e-3, 2.0]]                                    # thin but drawn, inradius ~1e-2 px
    pos[6][1] = pos[7][1] = pos[8][1] = 1.48 / 16       # the thin one straddles pixel centres at v = 17.5
    pos[8][1] += 1.25e-7                                # height 2e-6 px: inradius ~1e-6 px
    pos[9][1] = 1.52 / 16
    tri = [[0, 1, 2], [0, 3, 3], [3, 4, 5], [6, 7, 8], [6, 7, 9]]
    model = model_of(pos, tri)
    proj = ref.projection(model, eye_camera(), 1.0)
    assert list(proj.visible) == [True, False, False, False, True]
    # the thin triangle (inradius 0.01 px) is steep: float32 resolves its window to ~1e-5 / 0.01
    check(renderer, model, eye_camera(), 1.0, tol=1e-3)
    check(renderer, model, eye_camera(), 0.1, tol=1e-3)


def test_vertex_behind_on_near_plane_and_at_camera_centre(renderer):
    near = float(np.float32(0.01))
    pos = [[-0.5, -0.5, 2.0], [0.6, -0.4, 2.1], [0.0, 0.7, 1.9],
           [0.3, 0.3, -1.0],            # behind the camera
           [0.2, -0.2, near],           # exactly on the near plane (float32 0.01)
           [0.0, 0.0, 0.0]]             # at the camera centre
    tri = [[0, 1, 2], [0, 1, 3], [1, 2, 4], [2, 0, 5]]
    model = model_of(pos, tri, k=16)
    proj = ref.projection(model, eye_camera(), 1.0, near)
    assert list(proj.visible) == [True, False, False, False]
    _, g, _ = check(renderer, model, eye_camera(), 1.0, near=0.01)
    assert not np.any(g.v_positions[3:]) and not np.any(g.v_sh[3:]) and not np.any(g.v_opacity[3:])


def test_sigma_1e4_pixels_on_and_just_inside_edges(renderer):
    # u = 16 x + 16 at z = 2: pixel centres j + 0.5 lie exactly on x = (j + 0.5 - 16) / 16
    on = lambda j: (j + 0.5 - 16) / 16
    pos = [[on(4), on(6), 2.0], [on(26), on(6), 2.0], [on(4), on(28), 2.0],            # edges on pixel centres
           [on(8) - 1e-3 / 16, on(3) - 1e-3 / 16, 2.0],                # edges 1e-3 px outside centres
           [on(30) + 2e-3 / 16, on(3) - 1e-3 / 16, 2.0], [on(8) - 1e-3 / 16, on(25) + 2e-3 / 16, 2.0]]
    tri = [[0, 1, 2], [3, 4, 5]]
    model = model_of(pos, tri, opacity=0.6)
    # pixels 1e-3 px inside an edge have window ratio ~1e-4: float32 knows it to ~1e-3 relative,
    # and at sigma 1e-4 they carry most of the position gradient
    _, _, errs = check(renderer, model, eye_camera(), 1e-4, tol=1e-2)
    assert errs["v_sh"] <= 1e-4 and errs["v_opacity"] <= 1e-4


def test_opacity_exactly_zero_and_one(renderer):
    model, cam = random_scene(21, 32, 32, sheets=3, points_per_sheet=7)
    op = model.opacity.copy()
    op[:5] = 0.0
    op[5:12] = 1.0
    model = TriangleModel(model.positions, model.triangles, model.sh, op)
    res, g, _ = check(renderer, model, cam, 1.0)
    # every triangle holding an opacity-0 vertex is culled: those vertices get nothing
    assert not np.any(g.v_opacity[:5]) and not np.any(g.v_positions[:5]) and not np.any(g.v_sh[:5])
    assert np.any(g.v_opacity[5:12])
    check(renderer, model, cam, 0.1, tol=1e-3)


def test_screen_covering_triangle_stacked_1000_deep(renderer):
    n = 1000
    z = 1.0 + 0.01 * np.arange(n)
    pos = np.concatenate([np.column_stack([-3 * z, -3 * z, z]), np.column_stack([3 * z, -3 * z, z]),
                          np.column_stack([0 * z, 3 * z, z])])
    tri = np.column_stack([np.arange(n), n + np.arange(n), 2 * n + np.arange(n)])
    model = model_of(pos, tri, k=1, opacity=0.5)
    res, g, _ = check(renderer, model, eye_camera(), 1.0)
    assert res.n_contrib.max() < 100      # T < 1e-4 stops every pixel early
    assert np.any(g.v_opacity) and not np.any(g.v_opacity[n // 2:])


def test_10k_coplanar_triangles_at_identical_depth(renderer):
    rng = np.random.default_rng(4)
    m = 10_000
    centre = rng.uniform(-0.7, 0.7, size=(m, 1, 2)) * 3.0
    offs = rng.normal(scale=0.12, size=(m, 3, 2))
    xy = (centre + offs).reshape(-1, 2)
    pos = np.column_stack([xy, np.full(3 * m, 3.0)])
    tri = np.arange(3 * m).reshape(m, 3)
    model = model_of(pos, tri, k=1, opacity=0.3)
    res, g, _ = check(renderer, model, eye_camera(), 1.0)
    proj = ref.projection(f32_exact(model, eye_camera())[0], eye_camera(), 1.0)
    assert np.ptp(proj.depth[proj.visible]) == 0          # every centroid at the same depth
    # ties are drawn in triangle order, identically every time
    order = res.depth_order()
    vis = order[:int(proj.visible.sum())]
    assert np.all(np.diff(vis.astype(np.int64)) > 0)
    res2 = renderer.forward(res.model, res.camera, 1.0, (0.1, 0.2, 0.3))
    assert np.array_equal(res.image, res2.image)
    rng = np.random.default_rng(0)
    vi = rng.normal(size=res.image.shape)
    g1, g2 = renderer.backward(res, vi), renderer.backward(res2, vi)
    for name in GROUPS:
        assert np.array_equal(getattr(g1, name), getattr(g2, name))


def test_1m_triangles_outside_the_frustum(renderer):
    rng = np.random.default_rng(5)
    nv = 3000
    side = rng.uniform(1.0, 2.0, size=(nv, 3))
    pos = np.column_stack([side[:, 0] * 5 * side[:, 2], side[:, 1] - 0.5, side[:, 2]])   # right of the image
    pos[nv // 2:, 2] *= -1                                                               # behind the camera
    m = 1_000_000
    tri = rng.integers(0, nv // 2, size=(m, 3)) + np.where(np.arange(m) % 2 == 0, 0, nv // 2)[:, None]
    model = TriangleModel(pos, tri, np.zeros((nv, 1, 3)), np.full(nv, 0.5))
    t0 = time.perf_counter()
    res = renderer.forward(model, eye_camera(), 1.0)
    g = renderer.backward(res, np.ones((32, 32, 3)))
    assert time.perf_counter() - t0 < 30
    assert res.num_pairs == 0
    assert np.allclose(res.image, 0) and np.all(res.transmittance == 1)
    for name in GROUPS:
        assert not np.any(getattr(g, name))


@pytest.mark.parametrize("focal", [1e-3, 1e6])
def test_extreme_focal_lengths(renderer, focal):
    model, cam = random_scene(23, 32, 32, sheets=3, points_per_sheet=7)
    # the principal point on the centre of pixel (0, 0): at focal 1e-3 the whole scene is ~1e-3 px
    # wide around it, and near 0.5 float32 resolves it ~30x finer than near 16.5
    cx = 0.5 if focal < 1 else 16.5
    cam = Camera(32, 32, focal, focal, cx, cx, cam.world_to_camera)
    res, g, _ = check(renderer, model, cam, 1.0, tol=1e-3)
    if focal == 1e6:
        assert res.num_pairs > 0


@pytest.mark.parametrize("size", [(1, 1), (4097, 3)])
def test_tiny_and_very_wide_images(renderer, size):
    w, h = size
    model, _ = random_scene(24, 32, 32, sheets=3, points_per_sheet=7)
    cam = look_at_camera(w, h)
    res, g, _ = check(renderer, model, cam, 1.0)
    assert res.num_pairs > 0


def test_non_finite_inputs_are_rejected(renderer):
    model, cam = random_scene(25, 32, 32)
    for field in ("positions", "sh", "opacity"):
        kw = dict(positions=model.positions, triangles=model.triangles, sh=model.sh, opacity=model.opacity)
        for bad in (np.nan, np.inf):
            arr = np.array(kw[field], dtype=np.float64)
            arr.ravel()[0] = bad
            kw[field] = arr
            with pytest.raises(ValueError, match=field):
                TriangleModel(**kw)
    m = cam.world_to_camera.copy()
    m[0, 3] = np.inf
    with pytest.raises(ValueError, match="world_to_camera"):
        Camera(32, 32, 30.0, 30.0, 16.0, 16.0, m)
    with pytest.raises(ValueError, match="fx"):
        Camera(32, 32, np.nan, 30.0, 16.0, 16.0, np.eye(4))
    with pytest.raises(ValueError, match="sigma"):
        renderer.forward(model, cam, np.nan)
    with pytest.raises(ValueError, match="background"):
        renderer.forward(model, cam, 1.0, background=(0.0, np.inf, 0.0))
    res = renderer.forward(model, cam, 1.0)
    v = np.zeros((32, 32, 3))
    v[0, 0, 0] = np.inf
    with pytest.raises(ValueError, match="v_image"):
        renderer.backward(res, v)
    with pytest.raises(ValueError, match="sigma"):
        rb.backward(model, cam, np.inf, np.zeros((32, 32, 3)))
