"""Loaders on the real scenes in the shared data folder (cup: COLMAP, fox: instant-ngp with
distortion, chair: NeRF-synthetic).  The folder comes from $TSPLUS_DATA, default
``../shared/data`` beside the checkout."""

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from tsplus_wgpu.data import load_scene
from tsplus_wgpu.data.sfm import reprojection_errors, triangulate_known_poses

DATA = Path(os.environ.get("TSPLUS_DATA", Path(__file__).resolve().parents[3] / "shared" / "data"))


def scene_dir(name):
    d = DATA / name
    if not d.is_dir():
        pytest.skip(f"shared data scene {d} not found (set TSPLUS_DATA to the data folder)")
    return d


@pytest.fixture(scope="module")
def cup():
    return load_scene(scene_dir("cup"))


def test_cup_colmap(cup):
    assert cup.format == "colmap" and cup.points_source == "sfm"
    assert len(cup.cameras) == 77 and len(cup.points) == 9262
    assert cup.camera_models == {"SIMPLE_PINHOLE": 77}
    assert all(im.shape == (600, 800, 3) and im.dtype == np.float32 for im in cup.images)
    assert cup.image_names == sorted(cup.image_names)
    assert cup.test_indices == list(range(0, 77, 8)) and len(cup.train_indices) == 67
    assert cup.point_colors.min() >= 0 and cup.point_colors.max() <= 1


def test_cup_points_reproject_where_colmap_observed_them(cup):
    import pycolmap
    rec = pycolmap.Reconstruction(str(scene_dir("cup") / "sparse" / "0"))
    err = reprojection_errors(rec, cup.cameras, cup.image_names)
    assert len(err) == rec.compute_num_observations()
    # COLMAP's own mean reprojection error of this model is 0.59 px
    assert err.mean() < 1.0 and np.median(err) < 1.0
    # and exactly pycolmap's projection: the camera convention is the same
    im = rec.images[1]
    cam = cup.cameras[cup.image_names.index(im.name)]
    pid = [p.point3D_id for p in im.points2D if p.has_point3D()][:50]
    X = np.array([rec.points3D[i].xyz for i in pid])
    ours = X @ cam.R.T + cam.t
    ours = np.stack([cam.fx * ours[:, 0] / ours[:, 2] + cam.cx, cam.fy * ours[:, 1] / ours[:, 2] + cam.cy], 1)
    theirs = np.array([im.project_point(x) for x in X])
    np.testing.assert_allclose(ours, theirs, atol=1e-6)


def test_cup_downscale_and_subset():
    sc = load_scene(scene_dir("cup"), downscale=4, frames=["1.jpg", "10.jpg", "2.jpg"])
    assert sc.image_names == ["1.jpg", "10.jpg", "2.jpg"]
    assert sc.cameras[0].width == 200 and sc.images[0].shape == (150, 200, 3)
    # "1.jpg" is index 0 of the sorted scene: held out
    assert sc.test_indices == [0] and sc.train_indices == [1, 2]


def test_chair_nerf_synthetic():
    d = scene_dir("chair")
    sc = load_scene(d, frames=[0, 1, 2, 100, 101], points="none")
    assert sc.format == "nerf-synthetic" and sc.background == (1.0, 1.0, 1.0)
    assert sc.train_indices == [0, 1, 2] and sc.test_indices == [3, 4]
    img = sc.images[0]
    assert img.shape == (400, 400, 3)
    np.testing.assert_allclose(img[0, 0], 1.0)  # transparent corner composited on white
    meta = json.loads((d / "transforms_train.json").read_text())
    assert abs(sc.cameras[0].fx - 200 / np.tan(meta["camera_angle_x"] / 2)) < 1e-6
    # OpenGL -> OpenCV: every camera looks at the object near the origin
    for cam in sc.cameras:
        assert (cam.R @ np.zeros(3) + cam.t)[2] > 0
    full = load_scene(d, frames=[0], points="none")
    assert len(full.train_indices) == 1  # split computed over all 300 frames first


def test_fox_undistortion_by_triangulation(tmp_path):
    """Points triangulated with the known poses reproject well, and better with undistortion."""
    d = scene_dir("fox")
    sub = list(range(0, 24, 2))
    sc = load_scene(d, downscale=4, frames=sub, points="none", split="none")
    assert sc.format == "transforms" and sc.camera_models == {"OPENCV": 12}
    assert sc.images[0].shape == (480, 270, 3)
    _, _, info = triangulate_known_poses(sc.cameras, sc.images, sc.image_names, tmp_path / "a", progress=False)
    err_undist = reprojection_errors(info["reconstruction"], sc.cameras)
    # the same frames without the distortion coefficients
    meta = json.loads((d / "transforms.json").read_text())
    for k in ("k1", "k2", "p1", "p2"):
        meta.pop(k, None)
    for fr in meta["frames"]:
        fr["file_path"] = str(d / fr["file_path"])
    (tmp_path / "raw").mkdir()
    (tmp_path / "raw" / "transforms.json").write_text(json.dumps(meta))
    raw = load_scene(tmp_path / "raw", downscale=4, frames=sub, points="none", split="none")
    _, _, info_raw = triangulate_known_poses(raw.cameras, raw.images, raw.image_names, tmp_path / "b",
                                             progress=False)
    err_raw = reprojection_errors(info_raw["reconstruction"], raw.cameras)
    print(f"fox reprojection: undistorted {err_undist.mean():.3f} px ({len(err_undist)} obs), "
          f"raw {err_raw.mean():.3f} px ({len(err_raw)} obs)")
    assert len(err_undist) > 3000
    assert err_undist.mean() < 0.5
    assert err_undist.mean() < err_raw.mean()


def test_fox_points_auto_triangulates(tmp_path):
    sc = load_scene(scene_dir("fox"), downscale=8, frames=list(range(0, 10, 2)), cache_dir=tmp_path)
    assert sc.points_source == "triangulated" and len(sc.points) > 200
    assert any("triangulated" in w for w in sc.warnings)
    # triangulated points lie in front of the cameras that took the images
    front = np.mean([(sc.points @ c.R.T + c.t)[:, 2] > 0 for c in sc.cameras])
    assert front > 0.95
    again = load_scene(scene_dir("fox"), downscale=8, frames=list(range(0, 10, 2)), cache_dir=tmp_path)
    assert np.array_equal(again.points, sc.points)  # cached
    # triangulated at full size: another downscale reuses the same points
    other = load_scene(scene_dir("fox"), downscale=4, frames=list(range(0, 10, 2)), cache_dir=tmp_path)
    assert np.array_equal(other.points, sc.points) and any("cached" in w for w in other.warnings)
    # the key holds the images' bytes, not their file times: a fresh copy of the scene (every file
    # new) reuses the cache, a changed image does not (keyed on modification times until 2026-11-27,
    # every session's fresh copy of the shared data triangulated again)
    copy = shutil.copytree(scene_dir("fox"), tmp_path / "copy" / "fox", copy_function=shutil.copyfile)
    for f in copy.rglob("*"):
        os.utime(f, (1e9, 1e9))                             # and surely other times than the originals'
    again = load_scene(copy, downscale=8, frames=list(range(0, 10, 2)), cache_dir=tmp_path)
    assert np.array_equal(again.points, sc.points) and any("cached" in w for w in again.warnings)
    first = copy / json.loads((copy / "transforms.json").read_text())["frames"][2]["file_path"]  # training
    first.write_bytes(first.read_bytes() + b"\0")        # a JPEG decoder ignores what follows its end
    changed = load_scene(copy, downscale=8, frames=list(range(0, 10, 2)), cache_dir=tmp_path)
    assert not any("cached" in w for w in changed.warnings)


def test_lund_points_most_takes_the_larger_set_and_keeps_two_view_tracks(tmp_path, monkeypatch):
    """``points="most"`` (``tsplus train --points auto``): the SfM points or the points triangulated
    from the posed training views, whichever are more; the triangulation keeps two-view tracks."""
    d = scene_dir("lund")
    frames = list(range(0, 29, 3))
    sfm = load_scene(d, downscale=8, frames=frames, cache_dir=tmp_path)
    tri = load_scene(d, downscale=8, frames=frames, points="triangulate", cache_dir=tmp_path)
    most = load_scene(d, downscale=8, frames=frames, points="most", cache_dir=tmp_path)
    assert sfm.points_source == "sfm" and tri.points_source == "triangulated"
    lengths = np.diff(tri.point_tracks[0])
    print(f"lund, {len(frames)} frames: {len(sfm.points)} SfM points, {len(tri.points)} triangulated "
          f"({np.count_nonzero(lengths == 2)} two-view)")
    assert lengths.min() == 2 and np.count_nonzero(lengths == 2) > 0.2 * len(lengths)
    larger = tri if len(tri.points) > len(sfm.points) else sfm
    assert most.points_source == larger.points_source
    np.testing.assert_array_equal(most.points, larger.points)
    np.testing.assert_array_equal(most.point_tracks[0], larger.point_tracks[0])
    np.testing.assert_array_equal(most.point_tracks[1], larger.point_tracks[1])
    assert any(f"the {len(larger.points):,} " in w and "more than" in w for w in most.warnings)
    # and the other way round: more triangulated points than SfM ones
    import tsplus_wgpu.data.posed_points as posed_points
    many = np.tile(tri.points, (len(sfm.points) // len(tri.points) + 1, 1))
    monkeypatch.setattr(posed_points, "triangulated", lambda *a, **k: (many, np.zeros_like(many), None))
    other = load_scene(d, downscale=8, frames=frames, points="most", cache_dir=tmp_path)
    assert other.points_source == "triangulated" and other.point_tracks is None
    np.testing.assert_array_equal(other.points, many)
