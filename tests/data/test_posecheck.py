"""A photo whose given pose disagrees with its own matches (data/posecheck.py) is found by the
triangulation of posed photos and posed again from its matches (data/poserepair.py), or left out
of training and of the triangulation when they cannot pose it; photos whose poses are right are
never left out."""

from types import SimpleNamespace

import numpy as np
import pytest

from tsplus_wgpu.data import load_scene
from tsplus_wgpu.data import posecheck as P
from tsplus_wgpu.data import tracks as T
from tsplus_wgpu.data.guided import fundamental
from tsplus_wgpu.data.procedural import load_procedural
from tsplus_wgpu.types import Camera


def _k(c):
    return np.array([[c.fx, 0, c.cx], [0, c.fy, c.cy], [0, 0, 1.0]])


def test_sampson_distance_is_zero_for_true_matches_and_a_pixel_for_a_pixel_off():
    sc = load_procedural("tiny", seed=0)
    a, b = sc.cameras[0], sc.cameras[1]
    pts = sc.points[:200]
    x1, z1 = a.project(pts)
    x2, z2 = b.project(pts)
    ok = (z1 > 0) & (z2 > 0)
    x1, x2 = x1[ok], x2[ok]
    F = fundamental(_k(a), a.world_to_camera, _k(b), b.world_to_camera)
    assert len(x1) > 50 and P.sampson(F, x1, x2).max() < 1e-6
    # moved one pixel across its epipolar line: at most a pixel (the error is shared with the
    # first image's point), and linear in the offset
    line = np.c_[x1, np.ones(len(x1))] @ F.T
    normal = line[:, :2] / np.linalg.norm(line[:, :2], axis=1, keepdims=True)
    d = P.sampson(F, x1, x2 + normal)
    assert np.all(d <= 1 + 1e-9) and np.median(d) > 0.5
    np.testing.assert_allclose(P.sampson(F, x1, x2 + 0.5 * normal), d / 2, rtol=2e-3)
    # along the line: no distance
    assert P.sampson(F, x1, x2 + 3 * normal[:, ::-1] * [1, -1]).max() < 1e-6


class _Db:
    """A stand-in for pycolmap's database and module: three posed images, every pair's matches."""

    def __init__(self, keys, pairs):
        self.keys, self.pairs = keys, pairs

    # pycolmap's module
    class Database:
        @staticmethod
        def open(path):
            return path

    @staticmethod
    def pair_id_to_image_pair(pid):
        return pid

    # the database
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def read_two_view_geometries(self):
        return list(self.pairs), [type("G", (), {"inlier_matches": m})() for m in self.pairs.values()]

    def read_keypoints(self, i):
        return self.keys[i]


def _posed(cams):
    """A stand-in for a pycolmap Reconstruction of the cameras ``cams`` (ids from 1)."""
    ns = SimpleNamespace
    return ns(cameras={i + 1: ns(calibration_matrix=(lambda c=c: _k(c)), width=c.width, height=c.height)
                       for i, c in enumerate(cams)},
              images={i + 1: ns(name=f"{i}.png", camera_id=i + 1,
                                cam_from_world=ns(matrix=(lambda c=c: c.world_to_camera[:3])))
                      for i, c in enumerate(cams)})


def test_pose_errors_judge_each_photo_by_its_pairs(monkeypatch):
    """pose_errors on a stand-in database whose matches are the true projections: a photo whose
    pose was turned by 6 degrees gets many times the error of the others, and a pair of cameras
    at one centre (no epipolar geometry) is not counted."""
    sc = load_procedural("tiny", seed=0)
    cams = sc.cameras[:4]
    uv = [c.project(sc.points) for c in cams]
    seen = np.all([z > 0 for _, z in uv], axis=0)
    keys = {i + 1: uv[i][0][seen] for i in range(4)}
    n = int(seen.sum())
    m = np.stack([np.arange(n), np.arange(n)], 1)
    db = _Db(keys, {(a, b): m for a in range(1, 5) for b in range(a + 1, 5)})
    monkeypatch.setattr(_Db.Database, "open", staticmethod(lambda path: db))
    exact = P.pose_errors(_Db, "db", _posed(cams))
    assert n > 50 and all(e < 1e-9 and k == 3 for e, k in exact.values())
    err = P.pose_errors(_Db, "db", _posed(cams[:3] + [_turned(cams[3], 6.0)]))
    # each other photo has two exact pairs of three: its weighted median stays exact
    assert err["3.png"][0] > P.FLOOR and max(err[f"{i}.png"][0] for i in range(3)) < 1e-9
    assert P.left_out(err) == ["3.png"]
    # a second camera at the first one's centre: that pair is not judged, the others are
    twin = _posed([cams[0], Camera(cams[1].width, cams[1].height, cams[1].fx, cams[1].fy, cams[1].cx, cams[1].cy,
                                   cams[0].world_to_camera)] + cams[2:])
    got = P.pose_errors(_Db, "db", twin)
    assert got["0.png"][1] == 2 and got["1.png"][1] == 2 and got["2.png"][1] == 3
    assert P.weighted_median([(0.0, 5), (1.0, 4)]) == 0.0 and P.weighted_median([(0.0, 4), (1.0, 5)]) == 1.0


def test_only_the_odd_photo_out_is_left_out():
    ok = {f"{i}.jpg": (0.0004 + 0.0001 * (i % 3), 5) for i in range(12)}
    assert P.left_out(ok) == []
    one = dict(ok, **{"7.jpg": (0.006, 9)})                       # lund's 20.jpg: 15x the median photo
    assert P.left_out(one) == ["7.jpg"]
    bad, typical = P.disagreeing(one)
    assert bad == ["7.jpg"] and typical == pytest.approx(0.0005)
    assert P.left_out(dict(ok, **{"7.jpg": (0.0018, 9)})) == []    # 3.6x: the cup's worst is 2.9x
    tiny = {f"{i}.jpg": (1e-5, 5) for i in range(12)}              # a sharp scene: over RATIO x but under FLOOR
    assert P.left_out(dict(tiny, **{"7.jpg": (0.0015, 9)})) == []
    unjudged = dict(one, **{"8.jpg": (float("nan"), 1)})           # too few pairs: never left out
    assert P.left_out(unjudged) == ["7.jpg"]
    many = dict(ok, **{f"{i}.jpg": (0.01, 9) for i in range(5)})   # 5 of 12: the model, not a photo
    assert P.disagreeing(many)[0] and P.left_out(many) == []
    assert P.left_out({"a": (0.01, 3), "b": (0.0001, 3)}) == []     # too few photos to say


def _turned(cam, degrees):
    """The camera tilted about its own horizontal axis (its centre kept)."""
    t = np.radians(degrees)
    r = np.array([[1, 0, 0], [0, np.cos(t), -np.sin(t)], [0, np.sin(t), np.cos(t)]])
    w2c = cam.world_to_camera.copy()
    w2c[:3, :3] = r @ w2c[:3, :3]
    w2c[:3, 3] = r @ w2c[:3, 3]
    return Camera(cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy, w2c)


def _one_tilted(tmp_path, small, index):
    """``small`` written again as LLFF with camera ``index`` tilted by 8 degrees, and loaded."""
    from tests.data.test_formats import write_llff
    cams = list(small.cameras)
    cams[index] = _turned(cams[index], 8.0)
    small.cameras = cams
    write_llff(tmp_path / "bad", small)
    return load_scene(tmp_path / "bad", points="triangulate", cache_dir=tmp_path / "cache")


@pytest.mark.slow
def test_a_photo_with_a_wrong_pose_is_posed_again_from_its_matches(tmp_path):
    """The small procedural scene written as LLFF, one training camera tilted by 8 degrees in the
    file: the loader names it and poses it again from its matches to the points the other photos
    triangulate, within a small fraction of a degree and of the scene's spacing of the true pose,
    and trains with that pose; the points are triangulated with it in. With the right poses nothing
    is left out or posed again (about 6 s)."""
    from tests.data.test_formats import write_llff
    from tsplus_wgpu.data.poserepair import moved
    small = load_procedural("small", seed=0)
    write_llff(tmp_path / "good", small)
    good = load_scene(tmp_path / "good", points="triangulate", cache_dir=tmp_path / "cache")
    assert not any("pose disagrees" in w for w in good.warnings)
    assert len(good.train_indices) + len(good.test_indices) == len(good.cameras)
    wrong = good.train_indices[12]                 # a photo with enough matched pairs to be judged
    bad = _one_tilted(tmp_path, small, wrong)
    said = [w for w in bad.warnings if "pose disagrees" in w]
    assert len(said) == 1 and said[0].startswith(bad.image_names[wrong] + ":"), bad.warnings
    assert "posed again from" in said[0] and "trained with that pose" in said[0]
    assert bad.train_indices == good.train_indices and bad.test_indices == good.test_indices
    spacing = np.median([moved(good.cameras[i].world_to_camera, good.cameras[i + 1].world_to_camera)[0]
                         for i in range(len(good.cameras) - 1)])
    dist, turn = moved(good.cameras[wrong].world_to_camera, bad.cameras[wrong].world_to_camera)
    assert turn < 0.3 and dist < 0.05 * spacing, (turn, dist, spacing)
    assert moved(good.cameras[wrong].world_to_camera, _turned(good.cameras[wrong], 8.0).world_to_camera)[1] > 7.9
    others = [i for i in range(len(good.cameras)) if i != wrong]
    assert all(np.array_equal(good.cameras[i].world_to_camera, bad.cameras[i].world_to_camera) for i in others)
    assert wrong in set(np.unique(bad.point_tracks[1]))           # its matches make points again
    T.check(bad.point_tracks, len(bad.points), len(bad.cameras))
    again = load_scene(tmp_path / "bad", points="triangulate", cache_dir=tmp_path / "cache")   # cached
    assert again.train_indices == bad.train_indices and said[0] in again.warnings
    np.testing.assert_array_equal(again.cameras[wrong].world_to_camera, bad.cameras[wrong].world_to_camera)


@pytest.mark.slow
def test_a_photo_with_a_wrong_pose_that_cannot_be_posed_again_is_left_out(tmp_path, monkeypatch):
    """The same tilted camera when its matches are too few to pose it (the threshold raised past
    them): the loader names it, trains without it, and no initial point's track uses it. A
    checkpoint trained with the photo refuses to resume without it (about 3 s)."""
    from tests.data.test_formats import write_llff
    from tsplus_wgpu.data import poserepair
    small = load_procedural("small", seed=0)
    write_llff(tmp_path / "good", small)
    good = load_scene(tmp_path / "good", points="triangulate", cache_dir=tmp_path / "cache")
    wrong = good.train_indices[12]
    monkeypatch.setattr(poserepair, "MIN_MATCHES", 10 ** 9)
    bad = _one_tilted(tmp_path, small, wrong)
    said = [w for w in bad.warnings if "pose disagrees" in w]
    assert len(said) == 1 and said[0].startswith(bad.image_names[wrong] + ":"), bad.warnings
    assert "left out of training" in said[0]
    assert bad.train_indices == [i for i in good.train_indices if i != wrong]
    assert bad.test_indices == good.test_indices
    assert wrong not in set(np.unique(bad.point_tracks[1]))
    assert poserepair.moved(good.cameras[wrong].world_to_camera, bad.cameras[wrong].world_to_camera)[1] > 7.9
    T.check(bad.point_tracks, len(bad.points), len(bad.cameras))
    again = load_scene(tmp_path / "bad", points="triangulate", cache_dir=tmp_path / "cache")   # cached
    assert again.train_indices == bad.train_indices and said[0] in again.warnings
    # a checkpoint trained with the photo refuses to resume without it (and the other way round)
    from tsplus_wgpu.errors import UserError
    from tsplus_wgpu.train.checkpoint import check_fingerprint, data_fingerprint
    saved, now = data_fingerprint(good, "S"), data_fingerprint(bad, "S")
    assert saved["train"] != now["train"] and saved["pixels"] == now["pixels"]
    bad.points = good.points                      # the same count of points: the training views alone
    with pytest.raises(UserError, match="training views differ"):
        check_fingerprint("ckpt.npz", saved, data_fingerprint(bad, "S"))


def test_repose_recovers_a_pose_from_matches_with_outliers_and_refuses_too_few():
    """pycolmap's PnP on exact projections of the tiny scene's points, a third of them replaced by
    random pixels: the pose to 1e-6; with fewer matches than MIN_MATCHES, or most of them wrong,
    no pose. ``moved`` measures a known turn and shift."""
    import pycolmap

    from tsplus_wgpu.data import poserepair as R
    sc = load_procedural("small", seed=0)
    cam = sc.cameras[3]
    uv, z = cam.project(sc.points)
    inside = (z > 0) & (uv[:, 0] > 0) & (uv[:, 0] < cam.width) & (uv[:, 1] > 0) & (uv[:, 1] < cam.height)
    uv, xyz = uv[inside].astype(np.float64), sc.points[inside].astype(np.float64)
    rng = np.random.default_rng(0)
    bad = rng.random(len(uv)) < 1 / 3
    noisy = uv.copy()
    noisy[bad] = rng.random((int(bad.sum()), 2)) * [cam.width, cam.height]
    pc = pycolmap.Camera.create_from_model_name(1, "PINHOLE", cam.fx, cam.width, cam.height)
    pc.params = [cam.fx, cam.fy, cam.cx, cam.cy]
    got = R.repose(pycolmap, noisy, xyz, pc)
    assert len(uv) > 100 and got is not None
    assert got["matches"] == len(uv) and abs(got["inliers"] - int((~bad).sum())) <= 0.02 * len(uv)
    np.testing.assert_allclose(got["cam_from_world"], cam.world_to_camera[:3], atol=1e-6)
    assert R.repose(pycolmap, uv[:R.MIN_MATCHES - 1], xyz[:R.MIN_MATCHES - 1], pc) is None
    mostly = uv.copy()
    wrong = rng.random(len(uv)) < 0.7
    mostly[wrong] = rng.random((int(wrong.sum()), 2)) * [cam.width, cam.height]
    assert R.repose(pycolmap, mostly, xyz, pc) is None
    d, a = R.moved(cam.world_to_camera, _turned(cam, 8.0).world_to_camera)
    assert d < 1e-9 and a == pytest.approx(8.0)
    shifted = cam.world_to_camera.copy()
    shifted[:3, 3] += [0.3, 0.0, 0.4]
    assert R.moved(cam.world_to_camera, shifted) == pytest.approx((0.5, 0.0), abs=1e-6)


@pytest.mark.slow
def test_a_held_out_photo_with_a_wrong_pose_is_left_out_of_the_evaluation(tmp_path):
    """The same scene with one held-out camera tilted by 8 degrees: matched with its nearest
    training photos it is named and left out of the held-out views, while training and the
    initial points stay as they were; the check is cached beside the triangulation."""
    from tests.data.test_formats import write_llff
    from tsplus_wgpu.data import heldout_poses as H
    small = load_procedural("small", seed=0)
    write_llff(tmp_path / "good", small)
    good = load_scene(tmp_path / "good", points="triangulate", cache_dir=tmp_path / "cache")
    assert not any("held-out photo" in w for w in good.warnings), good.warnings
    entry = next((tmp_path / "cache").glob("tri_*"))
    with np.load(entry / H.RESULT) as z:                       # every held-out photo judged, all right
        assert len(z["errors"]) == len(good.test_indices) and np.all(np.isfinite(z["errors"]))
    wrong = good.test_indices[1]
    bad = _one_tilted(tmp_path, small, wrong)
    said = [w for w in bad.warnings if "held-out photo" in w]
    assert len(said) == 1 and said[0].startswith(bad.image_names[wrong] + ":"), bad.warnings
    assert "left out of the evaluation" in said[0]
    assert bad.test_indices == [i for i in good.test_indices if i != wrong]
    assert bad.train_indices == good.train_indices and np.array_equal(bad.points, good.points)
    again = load_scene(tmp_path / "bad", points="triangulate", cache_dir=tmp_path / "cache")   # cached
    assert again.test_indices == bad.test_indices and said[0] in again.warnings
    assert not list(entry.glob("heldout.tmp*"))


def test_the_held_out_rule_and_its_neighbours():
    """One odd held-out photo goes; a majority of them never does (the poses as a whole are
    off); nothing goes without a typical training error. Neighbours face the same way."""
    from tsplus_wgpu.data.heldout_poses import disagreeing_held_out, neighbours
    typical = 0.0005
    assert disagreeing_held_out([0.0004, 0.006, 0.0006, float("nan")], typical) == [1]
    assert disagreeing_held_out([0.006], typical) == [0]                        # one photo may always go
    assert disagreeing_held_out([0.006, 0.007, 0.0005], typical) == []          # 2 of 3: not the photos
    assert disagreeing_held_out([0.0015, 0.0004], 0.0002) == []                 # over 5x but under FLOOR
    assert disagreeing_held_out([0.006], float("nan")) == []
    small = load_procedural("tiny", seed=0)
    got = neighbours(small.cameras, small.train_indices, small.test_indices, k=3)
    for t, ns in got.items():
        assert len(ns) == 3 and set(ns) <= set(small.train_indices)
        assert all(small.cameras[j].R[2] @ small.cameras[t].R[2] > 0 for j in ns)
        far = max(np.linalg.norm(small.cameras[j].center - small.cameras[t].center) for j in ns)
        others = [np.linalg.norm(small.cameras[j].center - small.cameras[t].center) for j in small.train_indices]
        assert far <= np.sort(others)[5]                                        # among the nearest
