"""shaders/project/: sh_to_color and project_triangles, each alone, against their float64
twins on float32-exact inputs (the twin starts from the numbers the kernel reads)."""

import numpy as np
import pytest
from scenes import f32_exact, random_scene

from tsplus_wgpu import TriangleModel
from tsplus_wgpu.kernels.project import ProjectTriangles, ShToColor, frame_params
from tsplus_wgpu.reference.project import TRI2D, project_triangles, projection, sh_to_color
from scenes import submit as run

F32 = lambda a: np.asarray(a, np.float64).astype(np.float32)


def gpu_sh_to_color(ctx, positions, sh, cam):
    """Run ShToColor alone; returns (colors [N, 4] float32, the float32 camera centre the kernel read)."""
    stage = ShToColor(ctx)
    n, k = sh.shape[:2]
    params = frame_params(stage, cam, 1.0, num_vertices=n, sh_k=k)
    colors = ctx.buffer(16 * n)
    run(ctx, lambda enc: stage(enc, params, ctx.upload(F32(positions)), ctx.upload(F32(sh)), colors, n))
    return ctx.read(colors, np.float32, 4 * n).reshape(n, 4), F32(cam.center).astype(np.float64)


@pytest.mark.parametrize("n", [1, 255, 257, 3001])
@pytest.mark.parametrize("k", [1, 4, 9, 16])
def test_sh_to_color(ctx, max_dim, n, k):
    model, cam = f32_exact(*random_scene(n + k, 64, 48, sheets=1, points_per_sheet=max(n, 3), sh_k=k))
    pos, sh = model.positions[:n], model.sh[:n]
    center = F32(cam.center).astype(np.float64)
    if n > 1:
        pos[1] = center                                  # at the camera centre: the DC term only
    got, _ = gpu_sh_to_color(ctx, pos, sh, cam)
    ref = sh_to_color(pos, sh, center)
    assert np.all(got[:, 3] == 1.0)
    # float32 rounding of up to 16 terms of size <= ~1.5: a few 1e-7; any dropped or wrong
    # basis function moves some colour by ~0.1
    np.testing.assert_allclose(got, ref, atol=2e-6, rtol=1e-5)


def culled_extras(model, cam):
    """The model plus one triangle each that project_triangles must cull: behind the camera,
    below 1/255 opacity, degenerate (collinear on screen)."""
    behind = np.array([[0, 0, -5.0], [1, 0, -5.0], [0, 1, -5.0]])      # the camera sits at z = -4
    front = np.array([[0, 0, 0.0], [0.5, 0, 0.0], [0, 0.5, 0.0]])
    line = np.array([[0, 0, 0.0], [0.2, 0.2, 0.0], [0.4, 0.4, 0.0]])
    n = model.num_vertices
    pos = np.concatenate([model.positions, behind, front, line])
    tri = np.concatenate([model.triangles, n + np.arange(9).reshape(3, 3)])
    sh = np.concatenate([model.sh, np.zeros((9,) + model.sh.shape[1:])])
    op = np.concatenate([model.opacity, [0.9] * 3, [0.003] * 3, [0.9] * 3])
    return f32_exact(TriangleModel(pos, tri, sh, op), cam)


def gpu_project(ctx, model, colors, cam, sigma, near=0.01):
    stage = ProjectTriangles(ctx)
    m = model.num_triangles
    params = frame_params(stage, cam, sigma, near=near, num_vertices=model.num_vertices, num_triangles=m)
    out = dict(tris=ctx.buffer(stage.src.structs["Tri2D"].itemsize * m), pixel_rects=ctx.buffer(16 * m),
               depth_keys=ctx.buffer(4 * m), tri_ids=ctx.buffer(4 * m))
    up = lambda a, dt: ctx.upload(np.asarray(a, dt))
    run(ctx, lambda enc: stage(enc, params, up(model.positions, np.float32), up(model.triangles, np.uint32),
                               up(model.opacity, np.float32), up(colors, np.float32), out["tris"],
                               out["pixel_rects"], out["depth_keys"], out["tri_ids"], m))
    return (ctx.read(out["tris"], stage.src.structs["Tri2D"], m), ctx.read(out["pixel_rects"], np.int32, 4 * m)
            .reshape(m, 4), ctx.read(out["depth_keys"], np.uint32, m), ctx.read(out["tri_ids"], np.uint32, m))


SCENES = {"1x1-one": (1, 1, 1, 3), "17x33": (2, 17, 33, 8), "256x192": (3, 256, 192, 10), "640x480-many": (4, 640, 480, 90)}


@pytest.mark.parametrize("scene", list(SCENES))
@pytest.mark.parametrize("sigma", [1.0, 0.3, 1e-4])
def test_project_triangles(ctx, max_dim, scene, sigma):
    seed, w, h, pts = SCENES[scene]
    model, cam = culled_extras(*f32_exact(*random_scene(seed, w, h, sheets=3 if pts > 3 else 1,
                                                         points_per_sheet=pts)))
    colors = F32(sh_to_color(model.positions, model.sh, cam.center)).astype(np.float64)   # [N, 4]
    rec, rects, keys, ids = gpu_project(ctx, model, colors, cam, sigma)
    ref, ref_rects, ref_keys, ref_ids = project_triangles(model.positions, model.triangles, model.opacity, colors,
                                                          cam.R, cam.t, cam.fx, cam.fy, cam.cx, cam.cy, 0.01,
                                                          sigma, w, h)
    np.testing.assert_array_equal(ids, ref_ids)
    vis = (ref_rects[:, 0] <= ref_rects[:, 2]) & (ref_rects[:, 1] <= ref_rects[:, 3])
    assert not vis[-3:].any()                            # the three that must be culled
    np.testing.assert_array_equal((rects[:, 0] <= rects[:, 2]) & (rects[:, 1] <= rects[:, 3]), vis)
    np.testing.assert_array_equal(keys[~vis], 0xFFFFFFFF)
    np.testing.assert_array_equal(rects[~vis], np.tile([1, 1, 0, 0], ((~vis).sum(), 1)))
    for name in TRI2D.names:                            # culled: a zero record
        assert np.all(rec[name][~vis] == 0) and np.all(ref[name][~vis] == 0)
    # the depth key is the float32 depth's bits: within 4 ulps of the twin's depth rounded to float32
    assert np.abs(keys[vis].astype(np.int64) - ref_keys[vis].astype(np.int64)).max(initial=0) <= 4
    # pixel boxes: exact, but for a bound within rounding of a pixel centre
    diff = np.abs(rects.astype(np.int64) - ref_rects)[vis]
    assert diff.max(initial=0) <= 1 and (diff > 0).any(axis=1).mean() <= 0.01
    assert_records_close(rec, ref, model, cam, sigma, vis)


EPS = 2.0 ** -23    # float32 machine epsilon
ULPS = 8            # allowed error, in units of EPS times each field's scale (measured: <= 1.7)


def assert_records_close(rec, ref, model, cam, sigma, vis):
    """Float fields within ULPS float32 roundings of their scale. Where a field is computed
    through the inradius r = 2 area / perimeter (g_k = -n_k / r, the colour's slopes), the
    scale carries the triangle's condition kappa = (1 + max |p|) / r: area from rounded screen
    vertices p loses ~ max|p| / r ulps. A dropped or wrong term moves a field by O(1) relative
    (>> 8 * 2^-23 * kappa, with kappa < 2000 in these scenes)."""
    proj = projection(model, cam, sigma)
    m = int(vis.sum())
    kappa = (1 + np.abs(proj.verts2d[vis]).reshape(m, -1).max(axis=1)) / proj.inradius[vis]      # [m]
    gmax = np.abs(proj.g[vis]).reshape(m, -1).max(axis=1)
    cmax = np.abs(proj.vcolors[vis]).reshape(m, -1).max(axis=1)
    pmax = np.abs(proj.verts2d[vis]).reshape(m, -1).max(axis=1)
    tau = ref["tau"][vis]
    scale = {"s": 1 + pmax, "opacity": 0 * pmax, "depth": np.abs(ref["depth"][vis]),
             "tau": tau * (1 + np.abs(np.log(np.maximum(tau, 1e-300)))),   # exp2(log2(x) / sigma)
             "g0": kappa * gmax, "g1": kappa * gmax, "g2": kappa * gmax, "inradius": kappa * proj.inradius[vis],
             "color": 1 + cmax, "dcolor_dx": kappa * gmax * (1 + cmax), "dcolor_dy": kappa * gmax * (1 + cmax)}
    assert set(scale) == set(TRI2D.names)
    for name, sc in scale.items():
        err = np.abs(np.asarray(rec[name][vis], np.float64) - ref[name][vis]).reshape(m, -1).max(axis=1, initial=0)
        bad = err > ULPS * EPS * sc + 1e-38            # (1e-38: tau underflowing to zero at tiny sigma)
        assert not bad.any(), f"{name}: error {err[bad].max():.3g} over {ULPS} ulps of {sc[bad].min():.3g}"
