"""MeshRenderer (standard depth-tested wgpu render pipeline) against its float64 z-buffer twin,
supersampling, the near plane, and the splatting renderer on an opaque model."""

import numpy as np
import pytest
from scenes import f32_exact, look_at_camera, random_scene

from tsplus_wgpu import Camera, MeshRenderer, TriangleModel
from tsplus_wgpu.reference.mesh import colour_slope
from tsplus_wgpu.reference.mesh import mesh_raster as render_reference
from tsplus_wgpu.render.mesh_renderer import PARAMS_DTYPE


@pytest.fixture(scope="module")
def mr(ctx):
    return MeshRenderer(ctx)


def _flat(model, seed):
    """Unshared vertices, one random colour per triangle: coverage shows in the colours."""
    rng = np.random.default_rng(seed)
    pos = model.positions[model.triangles.ravel()]
    tri = np.arange(len(pos)).reshape(-1, 3)
    col = np.repeat(rng.uniform(0, 1, (len(tri), 3)), 3, axis=0)
    return pos, tri, col


def test_params_struct_matches_wgsl():
    from tsplus_wgpu.gpu import load_wgsl
    code = load_wgsl("mesh/mesh_raster").code
    assert "clip_from_world: mat4x4<f32>" in code and PARAMS_DTYPE.itemsize == 96


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
@pytest.mark.parametrize("interpolation", ["perspective", "linear"])
def test_coverage_depth_colour_match_twin(mr, seed, interpolation):
    """Coverage as the twin with vertices snapped to 1/256 px; depth and colour as the twin that
    interpolates them from the exact positions (llvmpipe) or from the snapped ones (an NVIDIA
    H100): Vulkan allows both, and one of the two must hold to float32 precision."""
    model, cam = f32_exact(*random_scene(seed, 97, 61, sh_k=1))     # 97*16 bytes: padded readback rows
    for mesh in (_flat(model, seed), (model.positions, model.triangles,
                                      np.random.default_rng(seed).uniform(0, 1, (model.num_vertices, 3)))):
        res = mr.render(mesh, cam, interpolation=interpolation)
        twins = {a: render_reference(mesh, cam, interpolation=interpolation, subpixel_bits=8, attributes_from=a)
                 for a in ("exact", "snapped")}
        _, _, tid, amb = twins["exact"]
        ok = ~(amb | twins["snapped"][3])
        assert amb.sum() < 10
        assert np.array_equal(res.coverage[ok] > 0, tid[ok] >= 0)
        errors = {a: (np.abs(res.image[ok] - ref[ok]).max(),
                      (np.abs(res.depth[ok] - depth[ok]) / (1e-6 + 2e-5 * depth[ok])).max())
                  for a, (ref, depth, _, _) in twins.items()}
        assert any(colour <= 2e-5 and depth <= 1 for colour, depth in errors.values()), errors
    # the two twins differ here by far more than the tolerance: the test tells them apart
    assert np.abs(twins["exact"][0] - twins["snapped"][0])[ok].max() > 1e-4


@pytest.mark.parametrize("interpolation", ["perspective", "linear"])
def test_colour_slope_is_the_twins_derivative(interpolation):
    """colour_slope (the tolerance of the tests that compare hardware-drawn colours) against central
    differences of the twin's colours, moving the image by +-h px; and the snapped twin stays within
    slope / 512 of the exact one, as a snap of <= 1/512 px per coordinate allows."""
    model, cam = random_scene(0, 97, 61, sh_k=1)
    mesh = (model.positions, model.triangles, np.random.default_rng(0).uniform(0, 1, (model.num_vertices, 3)))
    img, _, tid, amb = render_reference(mesh, cam, interpolation=interpolation)
    slope = colour_slope(mesh, cam, tid, interpolation)
    h, shifted = 1e-4, {}
    for key, (dx, dy) in {"x+": (h, 0), "x-": (-h, 0), "y+": (0, h), "y-": (0, -h)}.items():
        c2 = Camera(cam.width, cam.height, cam.fx, cam.fy, cam.cx - dx, cam.cy - dy, cam.world_to_camera)
        shifted[key] = render_reference(mesh, c2, interpolation=interpolation)
    same = (tid >= 0) & ~amb & np.logical_and.reduce([s[2] == tid for s in shifted.values()])
    fd = (np.abs(shifted["x+"][0] - shifted["x-"][0]) + np.abs(shifted["y+"][0] - shifted["y-"][0])).max(2) / (2 * h)
    assert same.sum() > 1000 and np.median(slope[same]) > 0.01
    np.testing.assert_allclose(slope[same], fd[same], rtol=1e-6)
    assert np.all(slope[tid < 0] == 0)
    snapped, _, tid_s, amb_s = render_reference(mesh, cam, interpolation=interpolation, subpixel_bits=8,
                                                attributes_from="snapped")
    both = same & (tid_s == tid) & ~amb_s
    assert np.all(np.abs(snapped - img).max(2)[both] <= slope[both] * 2.0 ** -9 * 1.05 + 1e-12)


def test_supersampling_is_the_block_mean(mr):
    model, cam = random_scene(5, 40, 30, sh_k=1)
    mesh = _flat(model, 5)
    s = 3
    big = mr.render(mesh, cam.scaled(s)).image
    small = mr.render(mesh, cam, supersample=s, background=(0.2, 0.3, 0.4))
    big_bg = mr.render(mesh, cam.scaled(s), background=(0.2, 0.3, 0.4)).image
    np.testing.assert_allclose(small.image, big_bg.reshape(30, s, 40, s, 3).mean((1, 3)), atol=1e-6)
    assert small.image.shape == (30, 40, 3) and big.shape == (90, 120, 3)
    assert 0 < small.coverage.mean() < 1


def test_near_plane(mr):
    cam = look_at_camera(32, 32, eye=(0, 0, -1))
    pos = np.array([[-0.5, -0.5, -1.005], [0.5, -0.5, 0.0], [0.0, 0.5, 0.0]])   # first vertex at z = -0.005
    mesh = (pos, np.array([[0, 1, 2]]), np.ones((3, 3)))
    assert mr.render(mesh, cam).coverage.sum() == 0                          # dropped, as the splatting model
    assert mr.render(mesh, cam, drop_near=False).coverage.sum() > 100       # clipped, as engines
    with pytest.raises(ValueError, match="supersample"):
        mr.render(mesh, cam, supersample=0)


def test_empty_mesh_draws_background(mr):
    cam = look_at_camera(8, 6)
    img = mr.render((np.zeros((0, 3)), np.zeros((0, 3), int), np.zeros((0, 3))), cam, background=(1, 0, 0)).image
    assert np.array_equal(img, np.broadcast_to(np.float32([1, 0, 0]), (6, 8, 3)))


def test_splatting_renderer_agrees_on_an_opaque_model(mr, renderer):
    """sigma 1e-4, opacity 1: the splatting render equals the mesh render except near edges
    (alpha is capped at 0.99 there, so 1% of the layer behind shows)."""
    model, cam = random_scene(3, 80, 60, sheets=2, sh_k=1)
    model = TriangleModel(model.positions, model.triangles, model.sh, np.ones(model.num_vertices))
    splat = renderer.forward(model, cam, 1e-4).image
    mesh = mr.render(model, cam, interpolation="linear").image
    _, _, tid, _ = render_reference(model, cam, interpolation="linear")
    pad = np.pad(tid, 1, mode="edge")
    interior = np.ones_like(tid, bool)
    for dy in (0, 1, 2):
        for dx in (0, 1, 2):
            interior &= pad[dy:dy + 60, dx:dx + 80] == tid
    assert interior.mean() > 0.5
    np.testing.assert_allclose(mesh[interior], splat[interior], atol=0.012)


def test_an_uploaded_mesh_draws_what_its_arrays_draw(ctx, mr):
    """``upload`` once, draw from several views: the same images, depths and coverage as the
    arrays drawn each time; editing the arrays afterwards does not reach the uploaded copy; a
    mesh is drawn only by the renderer that uploaded it."""
    model, cam = random_scene(4, 64, 48, sh_k=1)
    col = np.random.default_rng(4).uniform(0, 1, (model.num_vertices, 3))
    pos = model.positions.copy()
    mesh = mr.upload((pos, model.triangles, col))
    first = None
    for k, view in enumerate([cam, look_at_camera(64, 48, eye=(0.5, 0.3, -4.0))]):
        want = mr.render((model.positions, model.triangles, col), view, supersample=1 + k)
        got = mr.render(mesh, view, supersample=1 + k)
        first = want if first is None else first
        assert want.coverage.mean() > 0.2
        for a, b in ((got.image, want.image), (got.depth, want.depth), (got.coverage, want.coverage)):
            np.testing.assert_array_equal(a, b)
    pos += 10.0
    np.testing.assert_array_equal(mr.render(mesh, cam).image, first.image)
    with pytest.raises(ValueError, match="another MeshRenderer"):
        MeshRenderer(ctx).render(mesh, cam)
