"""MeshRenderer (standard depth-tested wgpu render pipeline) against its float64 z-buffer twin,
supersampling, the near plane, and the splatting renderer on an opaque model."""

import numpy as np
import pytest
from scenes import f32_exact, look_at_camera, random_scene

from tsplus_wgpu import MeshRenderer, TriangleModel
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
    model, cam = f32_exact(*random_scene(seed, 97, 61, sh_k=1))     # 97*16 bytes: padded readback rows
    for mesh in (_flat(model, seed), (model.positions, model.triangles,
                                      np.random.default_rng(seed).uniform(0, 1, (model.num_vertices, 3)))):
        res = mr.render(mesh, cam, interpolation=interpolation)
        ref, depth, tid, amb = render_reference(mesh, cam, interpolation=interpolation, subpixel_bits=8)
        ok = ~amb
        assert amb.sum() < 10
        assert np.array_equal(res.coverage[ok] > 0, tid[ok] >= 0)
        np.testing.assert_allclose(res.image[ok], ref[ok], atol=2e-5)
        np.testing.assert_allclose(res.depth[ok], depth[ok], rtol=2e-5, atol=1e-6)


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
