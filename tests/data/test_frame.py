"""WorldFrame: the normalised frame training works in (tsplus_wgpu/data/frame.py)."""

import json

import numpy as np
import pytest
from scenes import look_at_camera

from tsplus_wgpu.data import WorldFrame, load_procedural
from tsplus_wgpu.types import Camera


def _project(cam, pts):
    """Pixel coordinates ``[N, 2]`` and camera z ``[N]`` of world points, in float64."""
    x = pts @ cam.R.T + cam.t
    return np.stack([cam.fx * x[:, 0] / x[:, 2] + cam.cx, cam.fy * x[:, 1] / x[:, 2] + cam.cy], 1), x[:, 2]


def _cameras(offset, radius, n=5, seed=0):
    """``n`` cameras on a sphere of ``radius`` around ``offset``, looking at it."""
    rng = np.random.default_rng(seed)
    offset = np.asarray(offset, np.float64)
    cams = []
    for _ in range(n):
        d = rng.normal(size=3)
        cams.append(look_at_camera(64, 48, eye=offset + radius * d / np.linalg.norm(d), target=offset))
    return cams


def test_round_trips_and_json():
    f = WorldFrame(2.5e-3, (3.1e6, -2.7e6, 5.5e2))
    pts = np.random.default_rng(1).normal(size=(100, 3)) * 400 + f.offset
    np.testing.assert_allclose(f.to_world(f.to_frame(pts)), pts, rtol=1e-15, atol=1e-15 * 3.1e6)
    q = np.random.default_rng(2).normal(size=(100, 3))
    np.testing.assert_allclose(f.to_frame(f.to_world(q)), q, rtol=0, atol=1e-15 * 3.1e6 * f.scale * 4)
    assert f.to_frame(pts).dtype == np.float64 and f.to_frame(pts).shape == (100, 3)
    back = WorldFrame.from_json(json.loads(json.dumps(f.to_json())))
    assert back == f                                  # floats round-trip through JSON exactly
    assert WorldFrame.identity().to_json() == {"scale": 1.0, "offset": [0.0, 0.0, 0.0]}
    assert f.near_world(0.01) == 0.01 / 2.5e-3 and f.near_world() == f.near_world(0.01)
    for bad in ({"scale": 0.0, "offset": [0, 0, 0]}, {"scale": 1.0, "offset": [0, 0]},
                {"scale": float("nan"), "offset": [0, 0, 0]}, {"scale": 1.0}, [1.0, 0, 0, 0], None):
        with pytest.raises(ValueError):
            WorldFrame.from_json(bad)


def test_for_cameras_puts_the_centres_within_radius_one():
    cams = _cameras((3.1e6, -2.7e6, 120.0), 35.0, n=7)
    f = WorldFrame.for_cameras(cams)
    centres = np.stack([c.center for c in cams])
    np.testing.assert_allclose(f.offset, centres.mean(0), rtol=1e-15)
    r = np.linalg.norm(f.to_frame(centres), axis=1)
    assert abs(r.max() - 1.0) < 1e-9 and np.allclose(f.to_frame(centres).mean(0), 0.0, atol=1e-9)
    for c in cams:                                    # the frame cameras' centres are the mapped centres
        np.testing.assert_allclose(f.camera(c).center, f.to_frame(c.center[None])[0], atol=1e-9)
    assert WorldFrame.for_cameras(cams) == f          # deterministic


def test_camera_mapping_keeps_every_pixel():
    """A world point seen by a world camera and its frame point seen by the frame camera land on the
    same pixel, up to float64 rounding, also with a UTM-sized offset; camera z scales by ``scale``."""
    offset = (4.6e5, 5.3e6, 310.0)
    cams = _cameras(offset, 80.0, n=4, seed=3)
    f = WorldFrame.for_cameras(cams)
    pts = np.asarray(offset) + np.random.default_rng(4).uniform(-20, 20, size=(500, 3))
    for c in cams:
        fc = f.camera(c)
        assert (fc.width, fc.height, fc.fx, fc.fy, fc.cx, fc.cy) == (c.width, c.height, c.fx, c.fy, c.cx, c.cy)
        np.testing.assert_array_equal(fc.R, c.R)
        uv, z = _project(c, pts)
        uv_f, z_f = _project(fc, f.to_frame(pts))
        np.testing.assert_allclose(uv_f, uv, rtol=0, atol=1e-6)    # pixels; |world| ~ 5e6 costs ~1e-9 relative
        np.testing.assert_allclose(z_f, z * f.scale, rtol=1e-8)


def test_degenerate_centres_use_the_points_then_one():
    cam = look_at_camera(64, 48, eye=(10.0, 20.0, 30.0), target=(10.0, 20.0, 40.0))
    pts = np.random.default_rng(5).normal(size=(1000, 3)) * 3.0 + [10.0, 20.0, 40.0]
    f = WorldFrame.for_cameras([cam], pts)
    np.testing.assert_allclose(f.offset, cam.center)
    d = np.linalg.norm(pts - cam.center, axis=1)
    assert f.scale == pytest.approx(1.0 / np.percentile(d, 90), rel=1e-12)
    twin = Camera(64, 48, 50, 50, 32, 24, cam.world_to_camera)    # two cameras at the same place
    assert WorldFrame.for_cameras([cam, twin], pts) == f
    assert WorldFrame.for_cameras([cam]).scale == 1.0                 # no points: scale 1
    assert WorldFrame.for_cameras([cam], np.tile(cam.center, (4, 1))).scale == 1.0   # unusable points
    with pytest.raises(ValueError, match="no cameras"):
        WorldFrame.for_cameras([])


def test_scene_frame_uses_every_camera_and_maps_the_scene():
    sc = load_procedural("tiny")
    f = sc.frame()
    assert f == WorldFrame.for_cameras(sc.cameras, sc.points)
    fs = sc.in_frame(f)
    assert fs.images is sc.images and fs.train_indices == sc.train_indices
    np.testing.assert_allclose(fs.points, f.to_frame(sc.points))
    np.testing.assert_allclose(fs.gt_mesh.vertices, f.to_frame(sc.gt_mesh.vertices))
    np.testing.assert_allclose(fs.depths[1], sc.depths[1] * f.scale, rtol=1e-6)
    assert max(np.linalg.norm(c.center) for c in fs.cameras) == pytest.approx(1.0)
    assert sc.cameras[0].t is not fs.cameras[0].t and not np.allclose(sc.cameras[0].t, fs.cameras[0].t)
