"""The built-in procedural scene: determinism, speed, and ground-truth consistency."""

import time

import numpy as np
import pytest

from tsplus_wgpu.data import load_procedural, load_scene
from tsplus_wgpu.data.procedural import build_world, make_cameras, rasterize, surface_color
from tsplus_wgpu.types import Camera


@pytest.fixture(scope="module")
def tiny():
    return load_procedural("tiny", seed=0, point_noise=0.0)


def test_tiny_is_fast_and_well_formed(tiny):
    t = time.perf_counter()
    sc = load_procedural("tiny", seed=1)
    assert time.perf_counter() - t < 1.5
    assert sc.format == "procedural" and sc.points_source == "procedural"
    assert len(sc.cameras) == len(sc.images) == len(sc.masks) == len(sc.depths) == 8
    for img, m in zip(sc.images, sc.masks):
        assert img.shape == (48, 64, 3) and img.dtype == np.float32
        assert 0 <= img.min() and img.max() <= 1
        assert (m >= 0).all()  # closed room: every pixel sees a surface
    assert sc.points.shape[1] == 3 and sc.point_colors.shape == sc.points.shape and len(sc.points) > 500
    assert sc.test_indices == [0] and sc.train_indices == list(range(1, 8))
    assert len(sc.gt_mesh.object_names) >= 8
    assert set(np.unique(sc.gt_mesh.face_object)) == set(range(len(sc.gt_mesh.object_names)))
    # textured: plenty of distinct colours in every view
    for img in sc.images:
        assert img.reshape(-1, 3).std(0).mean() > 0.05


def test_deterministic_per_seed(tiny):
    again = load_procedural("tiny", seed=0, point_noise=0.0)
    for a, b in zip(tiny.images, again.images):
        assert np.array_equal(a, b)
    assert np.array_equal(tiny.points, again.points)
    other = load_procedural("tiny", seed=1, point_noise=0.0)
    assert not np.array_equal(tiny.images[1], other.images[1])


def test_load_scene_gives_procedural():
    sc = load_scene("procedural:tiny")
    assert sc.format == "procedural" and sc.gt_mesh is not None
    assert load_scene(None).format == "procedural"


def test_several_objects_visible(tiny):
    seen = set()
    for m in tiny.masks:
        seen |= set(np.unique(m).tolist())
    names = tiny.gt_mesh.object_names
    assert {names.index(n) for n in ("floor", "table", "sphere", "box_crate")} <= seen


def test_points_reproject_onto_their_pixels(tiny):
    """Noise-free surface points project where the rendered depth and colour agree."""
    sc = tiny
    checked = 0
    for cam, dep, img in zip(sc.cameras, sc.depths, sc.images):
        xc = sc.points @ cam.R.T + cam.t
        z = xc[:, 2]
        u = cam.fx * xc[:, 0] / z + cam.cx
        v = cam.fy * xc[:, 1] / z + cam.cy
        inside = (z > 0.1) & (u >= 1) & (u < cam.width - 1) & (v >= 1) & (v < cam.height - 1)
        i, j = v[inside].astype(int), u[inside].astype(int)
        d = dep[i, j]
        visible = np.abs(d - z[inside]) < 0.01 * z[inside] + 0.01
        # colour at the pixel equals the point colour (up to anti-aliasing at texture edges)
        col = img[i[visible], j[visible]]
        ref = sc.point_colors[inside][visible]
        err = np.abs(col - ref).max(1)
        assert np.median(err) < 0.06
        checked += int(visible.sum())
    assert checked > 1000


def test_depth_and_ids_match_the_mesh(tiny):
    """Rays through pixel centres, intersected with the GT mesh faces, give the rendered depth."""
    sc = tiny
    cam = sc.cameras[3]
    V, F = sc.gt_mesh.vertices, sc.gt_mesh.faces
    face, depth, point = rasterize(V, F, cam, ss=1)
    assert np.array_equal(np.where(face >= 0, sc.gt_mesh.face_object[np.maximum(face, 0)], -1), sc.masks[3])
    np.testing.assert_allclose(depth, sc.depths[3], rtol=1e-5)
    # the 3D surface point projects back to its own pixel centre
    xc = point.reshape(-1, 3) @ cam.R.T + cam.t
    u = cam.fx * xc[:, 0] / xc[:, 2] + cam.cx
    v = cam.fy * xc[:, 1] / xc[:, 2] + cam.cy
    jj, ii = np.meshgrid(np.arange(cam.width) + 0.5, np.arange(cam.height) + 0.5)
    np.testing.assert_allclose(u, jj.reshape(-1), atol=1e-6)
    np.testing.assert_allclose(v, ii.reshape(-1), atol=1e-6)
    # and lies on the plane of its face
    tri = V[F[face.reshape(-1)]]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    assert np.abs(np.einsum("ij,ij->i", point.reshape(-1, 3) - tri[:, 0], n)).max() < 1e-6


def test_rasterizer_single_triangle_and_near_clipping():
    """A triangle crossing the near plane is clipped, not dropped; coverage follows the edges."""
    cam = Camera(40, 30, 20.0, 20.0, 20.0, 15.0, np.eye(4))
    V = np.array([[-1.0, -1.0, 2.0], [1.0, -1.0, 2.0], [0.0, 1.0, 2.0]])
    face, depth, _ = rasterize(V, np.array([[0, 2, 1]]), cam, cull_backfaces=False)
    jj, ii = np.meshgrid(np.arange(40) + 0.5, np.arange(30) + 0.5)
    x, y = (jj - 20) / 20 * 2, (ii - 15) / 20 * 2  # on the plane z = 2
    inside = (y >= -1) & (x >= -1 + (y + 1) / 2 - 1e-9) & (x <= 1 - (y + 1) / 2 + 1e-9)
    assert np.array_equal(face >= 0, inside)
    np.testing.assert_allclose(depth[face >= 0], 2.0)
    # a floor-like triangle running from behind the camera to far in front
    V = np.array([[-5.0, 1.0, -3.0], [5.0, 1.0, -3.0], [0.0, 1.0, 20.0]])
    face, depth, point = rasterize(V, np.array([[0, 1, 2]]), cam, cull_backfaces=False)
    assert (face[20:] >= 0).any() and (face[:14] < 0).all()
    np.testing.assert_allclose(point[face >= 0][:, 1], 1.0, atol=1e-9)


def test_surface_color_matches_rendered_pixels():
    mesh = build_world(0)
    cam = make_cameras(8, 64, 48, 0)[2]
    face, _, point = rasterize(mesh[0], mesh[1], cam, ss=1)
    c = surface_color(point[face >= 0], face[face >= 0], mesh)
    assert c.shape[1] == 3 and 0 <= c.min() and c.max() <= 1
