"""A photo whose given pose disagrees with its own matches (data/posecheck.py) is found by the
triangulation of posed photos and left out of training and of the triangulation; photos whose
poses are right are never left out."""

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


@pytest.mark.slow
def test_a_photo_with_a_wrong_pose_is_left_out_of_training(tmp_path):
    """The small procedural scene written as LLFF, one training camera tilted by 8 degrees in the
    file: the loader names it, trains without it, and no initial point's track uses it; with the
    right poses nothing is left out (about 3 s)."""
    from tests.data.test_formats import write_llff
    small = load_procedural("small", seed=0)
    write_llff(tmp_path / "good", small)
    good = load_scene(tmp_path / "good", points="triangulate", cache_dir=tmp_path / "cache")
    assert not any("pose disagrees" in w for w in good.warnings)
    assert len(good.train_indices) + len(good.test_indices) == len(good.cameras)
    wrong = good.train_indices[12]                 # a photo with enough matched pairs to be judged
    cams = list(small.cameras)
    cams[wrong] = _turned(cams[wrong], 8.0)
    small.cameras = cams
    write_llff(tmp_path / "bad", small)
    bad = load_scene(tmp_path / "bad", points="triangulate", cache_dir=tmp_path / "cache")
    said = [w for w in bad.warnings if "pose disagrees" in w]
    assert len(said) == 1 and said[0].startswith(bad.image_names[wrong] + ":"), bad.warnings
    assert bad.train_indices == [i for i in good.train_indices if i != wrong]
    assert bad.test_indices == good.test_indices
    assert wrong not in set(np.unique(bad.point_tracks[1]))
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
