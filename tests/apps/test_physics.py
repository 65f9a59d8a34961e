"""tsplus_wgpu.physics: closest-point and ray queries against trimesh / brute force, and
rigid spheres dropped onto the procedural room, a single thin sheet and a slope."""

import math

import numpy as np
import pytest
import trimesh

from tsplus_wgpu import TriangleModel
from tsplus_wgpu.data.procedural import build_world
from tsplus_wgpu.apps.physics import MeshCollider, World, closest_point_on_triangles

G = 9.81


@pytest.fixture(scope="module")
def room():
    v, f, _, _ = build_world(0)
    return v, f


def sheet(z=0.0, half=1.0, normal_up=True):
    """One square of two triangles at height z (zero thickness)."""
    v = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]])
    f = np.array([[0, 1, 2], [0, 2, 3]]) if normal_up else np.array([[0, 2, 1], [0, 3, 2]])
    return v, f


def test_closest_point_on_triangles_matches_trimesh():
    rng = np.random.default_rng(0)
    a, b, c = rng.normal(size=(3, 5000, 3))
    p = rng.normal(size=(5000, 3)) * 2
    got = closest_point_on_triangles(p, a, b, c)
    ref = trimesh.triangles.closest_point(np.stack([a, b, c], 1), p)
    np.testing.assert_allclose(got, ref, atol=1e-12)


def test_closest_points_match_brute_force(room):
    v, f = room
    col = MeshCollider((v, f))
    rng = np.random.default_rng(1)
    p = rng.uniform(v.min(0), v.max(0), (400, 3))
    radius = rng.uniform(0.05, 0.6, 400)
    cp, dist, tri, nrm = col.closest_points(p, radius)
    t = v[f]
    allp = closest_point_on_triangles(np.repeat(p, len(f), 0), *(np.tile(t[:, k], (len(p), 1)) for k in range(3)))
    d = np.linalg.norm(np.repeat(p, len(f), 0) - allp, axis=1).reshape(len(p), len(f))
    best = d.min(1)
    within = best <= radius
    assert 50 < within.sum() < 400
    np.testing.assert_allclose(dist[within], best[within], atol=1e-12)
    assert np.all(np.isinf(dist[~within])) and np.all(tri[~within] == -1)
    # the normal is the triangle's, turned towards the point
    n = np.cross(t[tri[within], 1] - t[tri[within], 0], t[tri[within], 2] - t[tri[within], 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    assert np.allclose(np.abs(np.einsum("ij,ij->i", n, nrm[within])), 1.0)
    assert np.all(np.einsum("ij,ij->i", nrm[within], p[within] - cp[within]) >= -1e-12)


def _brute_ray(v, f, o, d):
    t = v[f]
    best = np.full(len(o), np.inf)
    for k, (oo, dd) in enumerate(zip(o, d)):
        e1, e2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
        pv = np.cross(dd, e2)
        det = np.einsum("ij,ij->i", e1, pv)
        tv = oo - t[:, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.einsum("ij,ij->i", tv, pv) / det
            qv = np.cross(tv, e1)
            w = (qv @ dd) / det
            s = np.einsum("ij,ij->i", e2, qv) / det
        ok = (u >= 0) & (w >= 0) & (u + w <= 1) & (s >= 0)
        if ok.any():
            best[k] = s[ok].min()
    return best


@pytest.mark.parametrize("backend", ["numpy", "embree"])
def test_raycast_first_hit(room, backend):
    if backend == "embree":
        pytest.importorskip("embreex")
    v, f = room
    col = MeshCollider((v, f), backend=backend)
    assert col.backend == backend
    rng = np.random.default_rng(2)
    o = rng.uniform([-3, -2.5, 0.1], [3, 2.5, 2.5], (300, 3))
    d = rng.normal(size=(300, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    dist, tri, nrm = col.raycast(o, d)
    ref = _brute_ray(v, f, o, d)
    assert np.all(np.isfinite(ref))          # inside a closed room every ray hits
    np.testing.assert_allclose(dist, ref, rtol=1e-6, atol=1e-9)
    assert np.all(np.einsum("ij,ij->i", nrm, d) <= 0)
    short, tri2, _ = col.raycast(o, d, max_distance=0.5)
    assert np.all(np.isinf(short[ref > 0.5])) and np.all(tri2[ref > 0.5] == -1)
    np.testing.assert_allclose(short[ref <= 0.5], ref[ref <= 0.5], rtol=1e-6, atol=1e-9)


def test_backend_auto_and_errors(room):
    col = MeshCollider(room)
    try:
        import embreex  # noqa: F401
        assert col.backend == "embree"
    except ImportError:
        assert col.backend == "numpy"
    with pytest.raises(ValueError, match="backend"):
        MeshCollider(room, backend="optix")
    with pytest.raises(ValueError, match="no triangles"):
        MeshCollider((np.zeros((3, 3)), np.zeros((0, 3), int)))
    w = World(room)
    with pytest.raises(ValueError, match="radius"):
        w.add_sphere((0, 0, 1), 0.0)
    with pytest.raises(ValueError, match="dt"):
        w.step(0.0)


def test_sphere_rests_on_the_room_floor(room):
    """Dropped from 2 m onto the floor (z = 0): never below it in 1000 steps of 1/60 s, at rest
    at z = radius."""
    world = World(room, restitution=0.5, friction=0.5)
    r = 0.1
    i = world.add_sphere((0.0, -1.8, 2.0), r)
    z = []
    for _ in range(1000):
        world.step(1 / 60)
        z.append(world.centers[i, 2])
    z = np.array(z)
    assert z.min() >= r - 0.5 * r                     # never more than half a radius into the floor
    assert abs(world.centers[i, 2] - r) < 1e-6        # at rest on it
    assert np.linalg.norm(world.velocities[i]) < 1e-6
    np.testing.assert_allclose(world.centers[i, :2], [0.0, -1.8], atol=1e-9)
    # it bounced: the first rebound peaks near e^2 times the fall height
    first = int(np.argmax(np.diff(z) > 0))
    peak = z[first:].max() - r
    assert abs(peak - 0.25 * (2.0 - r)) < 0.05 * (2.0 - r)


def test_model_and_file_inputs(tmp_path, room):
    from tsplus_wgpu.data import demo_model
    from tsplus_wgpu.io.export import export
    model = demo_model(0)
    export(model, tmp_path / "m.ply")
    for mesh in (model, tmp_path / "m.ply", trimesh.Trimesh(*room, process=False)):
        w = World(mesh)
        i = w.add_sphere((0.0, -1.8, 1.0), 0.2)
        for _ in range(120):
            w.step(1 / 30)
        assert abs(w.centers[i, 2] - 0.2) < 1e-4


@pytest.mark.parametrize("normal_up", [True, False])
def test_thin_sheet_holds_a_sphere(normal_up):
    """A single sheet of two triangles (no thickness, either winding) holds the sphere."""
    world = World(sheet(normal_up=normal_up), restitution=0.2)
    r = 0.05
    i = world.add_sphere((0.1, 0.2, 1.0), r)
    lowest = np.inf
    for _ in range(1000):
        world.step(1 / 60)
        lowest = min(lowest, world.centers[i, 2])
    assert lowest > 0.5 * r
    assert abs(world.centers[i, 2] - r) < 1e-6


@pytest.mark.parametrize("speed", [50.0, 500.0])
def test_fast_sphere_does_not_tunnel(speed):
    """Thrown at a thin sheet at up to 500 m/s (a 2 cm sphere moves 8 m per 1/60 s step):
    the substeps (each at most half a radius) never let the centre cross the sheet."""
    world = World(sheet(half=50.0), restitution=0.0, friction=0.0)
    r = 0.02
    i = world.add_sphere((0.0, 0.0, 10.0), r, velocity=(0.3, 0.0, -speed))
    zs = []
    for _ in range(60):
        world.step(1 / 60)
        zs.append(world.centers[i, 2])
    assert min(zs) > 0.0
    assert abs(zs[-1] - r) < 1e-6
    # and from the side, at a wall
    wall = World((sheet(half=50.0)[0][:, [2, 0, 1]], sheet()[1]), gravity=(0, 0, 0), restitution=1.0)
    j = wall.add_sphere((3.0, 0.0, 0.0), r, velocity=(-speed, 0.0, 0.0))
    for _ in range(5):
        wall.step(1 / 60)
        assert wall.centers[j, 0] > 0.0
    assert wall.velocities[j, 0] > 0.99 * speed        # bounced back (restitution 1)


@pytest.mark.parametrize("mu,slides", [(0.2, True), (1.0, False)])
def test_friction_on_a_slope(mu, slides):
    """On a 30 degree slope a sphere slides when mu < tan 30 = 0.577 and stays put otherwise;
    sliding, it accelerates at g (sin - mu cos)."""
    a = math.radians(30.0)
    v, f = sheet(half=20.0)
    rot = np.array([[math.cos(a), 0, -math.sin(a)], [0, 1, 0], [math.sin(a), 0, math.cos(a)]])
    v = v @ rot.T
    n = rot @ [0, 0, 1.0]
    world = World((v, f), restitution=0.0, friction=mu)
    r = 0.1
    i = world.add_sphere(n * r, r)
    steps = 60
    for _ in range(steps):
        world.step(1 / 60)
    moved = np.linalg.norm(world.centers[i] - n * r)
    dist_to_plane = float(np.dot(world.centers[i], n))
    assert abs(dist_to_plane - r) < 1e-6
    if slides:
        expect = 0.5 * G * (math.sin(a) - mu * math.cos(a)) * 1.0 ** 2
        assert abs(moved - expect) < 0.03 * expect
    else:
        assert moved < 1e-6


def test_many_spheres_and_timing(room):
    world = World(room)
    rng = np.random.default_rng(3)
    for _ in range(20):
        world.add_sphere(rng.uniform([-2.5, -2.0, 1.5], [2.5, 2.0, 2.4]), rng.uniform(0.05, 0.15))
    for _ in range(600):
        world.step(1 / 60)
    # everything ends up resting on something inside the room
    assert np.all(np.linalg.norm(world.velocities, axis=1) < 1e-3)
    lo, hi = room[0].min(0), room[0].max(0)
    assert np.all(world.centers > lo) and np.all(world.centers < hi)
    assert np.all(world.in_contact)


def test_model_type_check():
    with pytest.raises(Exception):
        World(TriangleModel(np.zeros((3, 3)), np.zeros((0, 3), int), np.zeros((3, 1, 3)), np.ones(3)))
