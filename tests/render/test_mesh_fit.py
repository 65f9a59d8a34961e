"""Vertex colours fitted to photos through the depth-tested mesh (render/mesh_fit.py): the id
pass against the float64 z-buffer twin (exactly), the barycentric coordinates against the
renderer's own perspective-correct interpolation, the least-squares fit recovering colours
that drew the photos, and the trainer's and the CLI's use of it."""

import numpy as np
import pytest
from scenes import f32_exact, look_at_camera, random_scene

from tsplus_wgpu import MeshRenderer
from tsplus_wgpu.types import Camera
from tsplus_wgpu.reference.mesh import colour_slope
from tsplus_wgpu.reference.mesh import mesh_raster as render_reference
from tsplus_wgpu.render.mesh_fit import (NormalEquations, barycentrics, fit_vertex_colors, triangle_ids,
                                         view_system)


@pytest.fixture(scope="module")
def mr(ctx):
    return MeshRenderer(ctx)


def _views(n=6, width=48, height=40, radius=4.0):
    cams = []
    for k in range(n):
        a = 2 * np.pi * k / n
        cams.append(look_at_camera(width, height, eye=(radius * np.sin(a), 0.4 * np.cos(3 * a), -radius * np.cos(a))))
    return cams


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_triangle_ids_match_twin(mr, seed):
    model, cam = f32_exact(*random_scene(seed, 97, 61, sh_k=1))
    mesh = (model.positions, model.triangles, np.zeros((model.num_vertices, 3)))
    ids = triangle_ids(mr, model.positions, model.triangles, cam, near=0.01)
    _, _, tid, amb = render_reference(mesh, cam, subpixel_bits=8)
    ok = ~amb
    assert amb.sum() < 10 and (tid[ok] >= 0).sum() > 500
    np.testing.assert_array_equal(ids[ok], tid[ok])


def test_triangle_ids_past_one_channel(mr):
    """Ids above 2048 use the second channel: the same scene behind 5000 unseen triangles."""
    model, cam = f32_exact(*random_scene(3, 64, 48, sh_k=1))
    far = np.zeros((3, 3)) + np.array([0.0, 0.0, -50.0])        # behind the camera: never drawn
    pos = np.concatenate([far, model.positions])
    tri = np.concatenate([np.zeros((5000, 3), np.int64) + [0, 1, 2], model.triangles + 3])
    ids = triangle_ids(mr, pos, tri, cam, near=0.01)
    ref = triangle_ids(mr, model.positions, model.triangles, cam, near=0.01)
    np.testing.assert_array_equal(ids, np.where(ref >= 0, ref + 5000, -1))


@pytest.mark.parametrize("seed", [0, 1])
def test_barycentrics_reproduce_the_renderers_colours(mr, seed):
    """Colours interpolated with the float64 ray/triangle barycentric coordinates equal the
    renderer's perspective-correct colours; screen-space (affine) weights would not."""
    model, cam = random_scene(seed, 80, 60, sh_k=1)
    col = np.random.default_rng(seed).uniform(0, 1, (model.num_vertices, 3))
    img = mr.render((model.positions, model.triangles, col), cam).image
    ids = triangle_ids(mr, model.positions, model.triangles, cam, near=0.01)
    r, c = np.nonzero(ids >= 0)
    b = barycentrics(model.positions, model.triangles, cam, ids[r, c], r, c)
    assert np.all(b >= 0) and np.allclose(b.sum(1), 1)
    mine = np.einsum("ki,kic->kc", b, col[model.triangles[ids[r, c]]])
    # a rasteriser may interpolate from vertices snapped to its 1/256 px grid (an NVIDIA H100 does):
    # each moves <= 1/512 px per coordinate, so a colour moves <= its slope / 512; twice that here
    tol = 2e-5 + colour_slope((model.positions, model.triangles, col), cam, ids)[r, c] * 2.0 ** -8
    assert np.all(np.abs(mine - img[r, c]).max(1) <= tol)
    # the same with affine screen-space weights is visibly off: the test sees perspective
    pc = model.positions @ cam.R.T + cam.t
    uv = np.stack([cam.fx * pc[:, 0] / pc[:, 2] + cam.cx, cam.fy * pc[:, 1] / pc[:, 2] + cam.cy], 1)
    t = model.triangles[ids[r, c]]
    p0, p1, p2 = uv[t[:, 0]], uv[t[:, 1]], uv[t[:, 2]]
    q = np.stack([c + 0.5, r + 0.5], 1)
    det = (p1[:, 0] - p0[:, 0]) * (p2[:, 1] - p0[:, 1]) - (p1[:, 1] - p0[:, 1]) * (p2[:, 0] - p0[:, 0])
    l1 = ((q[:, 0] - p0[:, 0]) * (p2[:, 1] - p0[:, 1]) - (q[:, 1] - p0[:, 1]) * (p2[:, 0] - p0[:, 0])) / det
    l2 = ((p1[:, 0] - p0[:, 0]) * (q[:, 1] - p0[:, 1]) - (p1[:, 1] - p0[:, 1]) * (q[:, 0] - p0[:, 0])) / det
    affine = np.einsum("ki,kic->kc", np.stack([1 - l1 - l2, l1, l2], 1), col[t])
    assert np.abs(affine - img[r, c]).max() > 1e-3 and (np.abs(affine - img[r, c]).max(1) > tol).mean() > 0.5


def _ray_barycentrics(positions, triangles, cam, ids, rows, cols):
    """The twin: each sample's ray against its triangle by Moller-Trumbore, a sample at a time."""
    out = np.zeros((len(ids), 3))
    p = np.asarray(positions, np.float64) @ cam.R.T + cam.t
    for k, (t, r, c) in enumerate(zip(ids, rows, cols)):
        p0, p1, p2 = p[triangles[t]]
        d = np.array([(c + 0.5 - cam.cx) / cam.fx, (r + 0.5 - cam.cy) / cam.fy, 1.0])
        e1, e2 = p1 - p0, p2 - p0
        h = np.cross(d, e2)
        det = e1 @ h
        b1, b2 = -p0 @ h / det, d @ np.cross(-p0, e1) / det
        b = np.clip([1.0 - b1 - b2, b1, b2], 0.0, None)
        out[k] = b / b.sum()
    return out


def test_barycentrics_match_the_ray_twin(mr):
    """The per-triangle planes give each sample's barycentric coordinates as the ray/triangle
    intersection does, to rounding; dropping a plane's term fails it."""
    model, cam = random_scene(5, 64, 48, sh_k=1)
    ids = triangle_ids(mr, model.positions, model.triangles, cam, near=0.01)
    r, c = np.nonzero(ids >= 0)
    b = barycentrics(model.positions, model.triangles, cam, ids[r, c], r, c)
    twin = _ray_barycentrics(model.positions, model.triangles, cam, ids[r, c], r, c)
    assert len(r) > 500 and np.abs(twin - np.clip(twin, 1e-6, None)).max() < 1e-3   # centres inside
    np.testing.assert_allclose(b, twin, rtol=0, atol=1e-12)
    assert barycentrics(model.positions, model.triangles, cam, ids[r, c][:0], r[:0], c[:0]).shape == (0, 3)


def _dense_system(mr, positions, triangles, cam, image, s, bg):
    """The twin of one view's normal equations: the dense A (a row a pixel: the mean of its s x s
    samples' barycentric rows), then A^T A and A^T y."""
    big = Camera(cam.width * s, cam.height * s, cam.fx * s, cam.fy * s, cam.cx * s, cam.cy * s, cam.world_to_camera)
    ids = triangle_ids(mr, positions, triangles, big, near=0.01)
    r, c = np.nonzero(ids >= 0)
    b = _ray_barycentrics(positions, triangles, big, ids[r, c], r, c)
    a = np.zeros((cam.width * cam.height, len(positions)))
    pix = (r // s) * cam.width + c // s
    for k in range(3):
        np.add.at(a, (pix, triangles[ids[r, c], k]), b[:, k] / (s * s))
    cover = np.bincount(pix, minlength=len(a)) / (s * s)
    y = image.reshape(-1, 3) - np.outer(1 - cover, bg)
    return a.T @ a, a.T @ y, pix, ids


@pytest.mark.parametrize("s", [1, 2, 3])
def test_normal_equations_match_the_dense_twin(mr, s):
    """A^T A from the per-triangle blocks and the straddling pixels' own terms, and A^T y from
    the samples, equal the dense products over two views (at 2x2 and 3x3 samples some pixels
    straddle triangles); leaving the straddling pixels out fails it."""
    model, _ = random_scene(6, 40, 32, sh_k=1)
    cams = _views(2, 40, 32)
    rng = np.random.default_rng(6)
    imgs = [rng.uniform(0, 1, (32, 40, 3)) for _ in cams]
    bg = np.array([0.3, 0.6, 0.1])
    eq = NormalEquations(model.triangles, model.num_vertices)
    ata, aty, mixed = 0.0, 0.0, 0
    for cam, img in zip(cams, imgs):
        cover = eq.add_view(mr, model.positions, cam, img, 0.01, supersample=s, background=bg)
        m, v, pix, ids = _dense_system(mr, model.positions, model.triangles, cam, img, s, bg)
        ata, aty = ata + m, aty + v
        np.testing.assert_allclose(cover.ravel(), np.bincount(pix, minlength=cover.size) / (s * s), atol=0)
        grid = ids.reshape(32, s, 40, s).transpose(0, 2, 1, 3).reshape(-1, s * s)
        mixed += int(sum(len(set(g[g >= 0])) > 1 for g in grid))
    assert (mixed > 20) == (s > 1) and np.abs(ata).max() > 1
    np.testing.assert_allclose(eq.ata().toarray(), ata, rtol=0, atol=1e-12)
    np.testing.assert_allclose(eq.aty, aty, rtol=0, atol=1e-12)
    if s > 1:
        eq.mixed = None
        assert np.abs(eq.ata().toarray() - ata).max() > 1e-3


def test_view_system_is_the_supersampled_render(mr):
    """A c equals the renderer's s x s supersampled image minus the background's share."""
    model, cam = random_scene(4, 40, 30, sh_k=1)
    col = np.random.default_rng(4).uniform(0, 1, (model.num_vertices, 3))
    bg = (0.2, 0.9, 0.4)
    img = mr.render((model.positions, model.triangles, col), cam, supersample=2, background=bg).image
    ata, aty, cover = view_system(mr, model.positions, model.triangles, cam, img, 0.01, supersample=2,
                                  background=bg)
    assert 0.1 < cover.mean() < 0.99                 # the background's share matters here
    # the normal equations of an image drawn by c itself are solved by c: A^T A c = A^T y
    np.testing.assert_allclose(ata @ col, aty, atol=1e-4 * np.abs(aty).max())


def test_fit_recovers_the_colours_that_drew_the_photos(mr):
    model, _ = random_scene(7, 48, 40, sh_k=1)
    rng = np.random.default_rng(7)
    truth = rng.uniform(0.05, 0.95, (model.num_vertices, 3))
    prior = np.full_like(truth, 0.5)
    cams = _views()
    bg = (1.0, 1.0, 1.0)
    photos = [mr.render((model.positions, model.triangles, truth), c, supersample=2, background=bg).image
              for c in cams]
    fit, info = fit_vertex_colors(model.positions, model.triangles, cams, photos, prior, 0.01, mr,
                                  supersample=2, background=bg, tol=1e-10)
    for c, photo in zip(cams, photos):
        again = mr.render((model.positions, model.triangles, fit), c, supersample=2, background=bg).image
        assert np.abs(again - photo).max() < 2e-3
    assert info["objective_fit"] < info["objective_prior"]
    ata, _, _ = view_system(mr, model.positions, model.triangles, cams[0], photos[0], 0.01, background=bg)
    seen = ata.diagonal() > 1.0                       # vertices a view sees over more than a pixel
    assert seen.sum() > 5
    np.testing.assert_allclose(fit[seen], truth[seen], atol=2e-2)
    # a vertex no photo sees keeps its prior exactly
    pos = np.concatenate([model.positions, [[0.0, 0.0, 40.0], [0.1, 0.0, 40.0], [0.0, 0.1, 40.0]]])
    far = np.array([[0, 1, 2]]) + model.num_vertices
    tri = np.concatenate([model.triangles, far])
    hidden, _ = fit_vertex_colors(pos, tri, cams[:1], photos[:1], np.full((len(pos), 3), 0.25), 0.01, mr)
    np.testing.assert_array_equal(hidden[-3:], 0.25)


def test_trainer_fits_the_exported_colours(renderer):
    """The fitted colours draw the training views closer than SH DC (mesh renderer, the
    photos at the training size)."""
    from tsplus_wgpu.data.procedural import load_procedural
    from tsplus_wgpu.train.trainer import TrainConfig, Trainer
    tiny = load_procedural("tiny")
    out = {}
    for mode in ("dc", "fit"):
        t = Trainer(tiny, TrainConfig(iterations=30, quick=True, topology=False, mesh_colors=mode, log_every=0,
                                      remove_shards=False, color_detail=False),   # the same geometry in both
                    renderer=renderer)
        t.train(progress=False, checkpoint_at_end=False)
        out[mode] = t.final_mesh()
    np.testing.assert_array_equal(out["dc"][1], out["fit"][1])
    assert not np.allclose(out["dc"][2], out["fit"][2], atol=1e-3)
    mr = MeshRenderer(renderer.ctx)
    near = tiny.frame().near_world()
    err = {m: np.mean([np.mean((mr.render((p, tr, col), tiny.cameras[v], supersample=2, near=near).image
                                - tiny.images[v]) ** 2) for v in tiny.train_indices])
           for m, (p, tr, col) in out.items()}
    assert err["fit"] < 0.95 * err["dc"]


def test_the_fit_samples_large_views_once_a_pixel():
    """2x2 samples a pixel up to MAX_SAMPLES a view: every CPU plan's size (at most 32,768
    pixels) and 480x270 keep 2x2; 960x540 and larger fit at 1x1 (2x2 cost 3.3-3.8x the time
    there for the same held-out PSNR: docs/measurements.md)."""
    from tsplus_wgpu.render.mesh_fit import fit_supersample
    from tsplus_wgpu.types import Camera

    def cam(w, h):
        return Camera(w, h, w, w, w / 2, h / 2, np.eye(4))
    assert [fit_supersample(cam(w, h), 2) for w, h in ((240, 135), (200, 150), (480, 270))] == [2, 2, 2]
    assert [fit_supersample(cam(w, h), 2) for w, h in ((960, 540), (800, 600), (1920, 1080))] == [1, 1, 1]
    assert fit_supersample(cam(240, 135), 4) == 4 and fit_supersample(cam(240, 135), 0) == 1
