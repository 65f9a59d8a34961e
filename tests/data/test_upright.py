"""Which way is up, from the cameras (tsplus_wgpu.data.upright): synthetic captures with a known
up in a randomly turned world, photos stored sideways with and without EXIF, the shared cup and
lund against the planes of their table and street, and ``tsplus export --y-up``."""

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest

from tsplus_wgpu.data import upright as U
from tsplus_wgpu.data.upright import Upright, engine_rotation, estimate_up, exif_up_axis

DATA = Path(os.environ.get("TSPLUS_DATA", Path(__file__).resolve().parents[3] / "shared" / "data"))


def _turn(rng):
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def _camera(yaw, pitch, roll, sideways=False):
    """World-to-camera rotation (OpenCV rows: right, down, forward) in a z-up world; sideways:
    the photo stored turned a quarter anticlockwise (EXIF orientation 6), raw x = display down."""
    f = np.array([math.cos(pitch) * math.cos(yaw), math.cos(pitch) * math.sin(yaw), math.sin(pitch)])
    r0 = np.cross(f, [0.0, 0.0, 1.0])
    r0 /= np.linalg.norm(r0)
    d0 = np.cross(f, r0)
    r = math.cos(roll) * r0 + math.sin(roll) * d0
    d = -math.sin(roll) * r0 + math.cos(roll) * d0
    return np.stack([d, -r, f]) if sideways else np.stack([r, d, f])


def _capture(rng, n, yaw, pitch, roll_deg, sideways=False):
    """``n`` cameras in a randomly turned world, and the true up."""
    q = _turn(rng)
    rots = [_camera(math.radians(rng.uniform(*yaw)), math.radians(rng.uniform(*pitch)),
                    math.radians(rng.normal(0.0, roll_deg)), sideways) @ q.T for _ in range(n)]
    return np.stack(rots), q @ [0.0, 0.0, 1.0], q


def _deg(a, b):
    return math.degrees(math.acos(float(np.clip(np.dot(a, b), -1.0, 1.0))))


def test_an_orbit_looking_down_finds_up_not_the_mean_view():
    rng = np.random.default_rng(0)
    rots, up, _ = _capture(rng, 40, (0, 250), (-50, -15), 2.0)      # a partial orbit, all looking down
    est = estimate_up(rots)
    assert _deg(est.up, up) < 1.5
    assert est.how == "the cameras' horizontal image axes" and est.sideways == 0
    mean_up = -rots[:, 1].mean(0)
    assert _deg(mean_up / np.linalg.norm(mean_up), up) > 5         # what the viewer used before
    assert 1.0 < est.rms_roll_deg < 3.0


def test_a_few_tilted_photos_do_not_tilt_the_scene(monkeypatch):
    rng = np.random.default_rng(5)
    rots, up, q = _capture(rng, 40, (0, 250), (-50, -15), 2.0)
    for k in range(5):                                                  # one photo in eight taken at a 40 deg slant
        rots[8 * k] = _camera(math.radians(50 * k), math.radians(-30), math.radians(40)) @ q.T
    assert _deg(estimate_up(rots).up, up) < 1.5
    monkeypatch.setattr(U, "_ROLL_SCALE", 10.0)                         # every camera weighted alike
    assert _deg(estimate_up(rots).up, up) > 2.5


def test_a_walk_facing_one_way_takes_the_mean_up(monkeypatch):
    rng = np.random.default_rng(1)
    rots, up, q = _capture(rng, 30, (-6, 6), (-3, 3), 2.0)
    rots[7] = _camera(0.1, math.radians(-55), math.radians(-30)) @ q.T   # one camera far off (misregistered)
    est = estimate_up(rots)
    assert est.how.startswith("the cameras' mean up")
    assert _deg(est.up, up) < 3.0
    monkeypatch.setattr(U, "_SPREAD_LO", 0.0)                       # the perpendicular alone: pitch and up
    monkeypatch.setattr(U, "_SPREAD_HI", 1e-9)                      # cannot be told apart
    assert _deg(estimate_up(rots).up, up) > 5.0


def test_sideways_photos_without_exif_are_recognised():
    rng = np.random.default_rng(2)
    rots, up, _ = _capture(rng, 30, (0, 300), (-40, -10), 2.0, sideways=True)
    est = estimate_up(rots)
    assert est.sideways == 30 and _deg(est.up, up) < 1.5
    upright = estimate_up(rots, [np.array([0.0, -1.0, 0.0])] * 30)   # told they are upright: wrong by a quarter turn
    assert _deg(upright.up, up) > 45


def test_exif_axes_decide_photo_by_photo():
    rng = np.random.default_rng(3)
    q = _turn(rng)
    cams, axes = [], []
    for k in range(24):
        side = k % 2 == 1
        cams.append(_camera(math.radians(15 * k), math.radians(-20), math.radians(rng.normal(0, 1)), side) @ q.T)
        axes.append(np.array([-1.0, 0.0, 0.0]) if side else np.array([0.0, -1.0, 0.0]))
    est = estimate_up(cams, axes)
    assert _deg(est.up, q @ [0, 0, 1]) < 1.0 and est.sideways == 0
    assert _deg(estimate_up(cams).up, q @ [0, 0, 1]) > 5.0            # mixed orientations need the EXIF


def test_exif_up_axis(tmp_path):
    from PIL import Image
    im = Image.new("RGB", (8, 6), (10, 20, 30))
    for o, axis in ((1, (0, -1, 0)), (3, (0, 1, 0)), (6, (-1, 0, 0)), (8, (1, 0, 0))):
        ex = im.getexif()
        ex[0x0112] = o
        im.save(tmp_path / f"o{o}.jpg", exif=ex.tobytes())
        np.testing.assert_array_equal(exif_up_axis(tmp_path / f"o{o}.jpg"), axis)
    im.save(tmp_path / "plain.png")
    assert exif_up_axis(tmp_path / "plain.png") is None
    (tmp_path / "junk.jpg").write_bytes(b"not a photo")
    assert exif_up_axis(tmp_path / "junk.jpg") is None and exif_up_axis(tmp_path / "missing.jpg") is None


def test_engine_rotation_and_the_record():
    rng = np.random.default_rng(4)
    rots, up, _ = _capture(rng, 20, (0, 90), (-20, 0), 1.0)
    est = estimate_up(rots)
    a = engine_rotation(est)
    np.testing.assert_allclose(a @ a.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(a) == pytest.approx(1.0)
    np.testing.assert_allclose(a @ est.up, [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(a @ est.forward, [0, 0, -1], atol=1e-12)
    mean_view = rots[:, 2].mean(0)
    assert (a @ mean_view)[2] < 0                                      # an engine camera down -Z sees the photos' side
    back = Upright.from_dict(json.loads(json.dumps(est.as_dict())))
    assert _deg(back.up, est.up) < 1e-4 and back.how == est.how
    for bad in (None, {}, {"up": [0, 0, 0], "forward": [1, 0, 0]}, {"up": [0, 1, 0], "forward": [0, 2, 0]},
                {"up": [float("nan"), 0, 1], "forward": [1, 0, 0]}, {"up": "x", "forward": 3}):
        assert Upright.from_dict(bad) is None
    assert estimate_up(np.zeros((0, 3, 3))) is None
    one = estimate_up(rots[:1])                                        # one camera: its own up
    assert _deg(one.up, -rots[0, 1]) < 1e-9


def _plane_normal(points, up, scale, seed=0):
    """The normal of the plane holding the most points among planes within 30 degrees of ``up``
    (RANSAC), refit to its points, and the points' heights above it."""
    rng = np.random.default_rng(seed)
    best = (0, None)
    for _ in range(1500):
        i = rng.choice(len(points), 3, replace=False)
        n = np.cross(points[i[1]] - points[i[0]], points[i[2]] - points[i[0]])
        if np.linalg.norm(n) < 1e-12:
            continue
        n /= np.linalg.norm(n)
        if abs(n @ up) < math.cos(math.radians(30)):
            continue
        inl = np.abs((points - points[i[0]]) @ n) < 0.01 * scale
        if inl.sum() > best[0]:
            best = (int(inl.sum()), inl)
    q = points[best[1]]
    n = np.linalg.svd(q - q.mean(0))[2][2]
    return n * np.sign(n @ up), q.mean(0)


@pytest.mark.parametrize("name", ["cup", "lund"])
def test_the_shared_captures_stand_on_their_table_and_street(name):
    from tsplus_wgpu.data.loader import load_scene
    if not (DATA / name).is_dir():
        pytest.skip(f"{DATA / name} missing")
    scene = load_scene(DATA / name, split="none", downscale=8)
    est = U.scene_upright(scene)
    pts = scene.points
    scale = float(np.median(np.linalg.norm(pts - np.median(pts, 0), axis=1)))
    n, origin = _plane_normal(pts, est.up, scale)
    assert _deg(n, est.up) < 5.0
    centres = np.stack([c.center for c in scene.cameras])
    assert np.mean((centres - origin) @ est.up > 0) > 0.6              # the cameras are above it
    assert "\nup:         (" in scene.summary()                          # what `tsplus inspect` prints
    if name == "cup":                                                   # its photos are stored sideways, no EXIF
        assert est.sideways == len(scene.cameras) and est.rms_roll_deg < 10
        assert f"{len(scene.cameras)} photos stored sideways" in scene.summary()
        assert np.mean((pts - origin) @ est.up > 0.02 * scale) > 0.5   # the cup stands on the table
    else:                                                               # a street walked one way
        assert est.how.startswith("the cameras' mean up")


def test_scene_upright_reads_each_photos_exif(tmp_path):
    """The cup's cameras with their photos tagged as a phone tags a portrait photo (orientation
    6: known sideways, the same up as recognised without EXIF), and tagged the other way round
    (orientation 8: up is +x, so the estimate turns over)."""
    from types import SimpleNamespace

    from PIL import Image

    from tsplus_wgpu.data.loader import load_scene
    if not (DATA / "cup").is_dir():
        pytest.skip(f"{DATA / 'cup'} missing")
    cup = load_scene(DATA / "cup", split="none", downscale=8, points="none")
    plain = U.scene_upright(cup)
    ups = {}
    for o in (6, 8):
        folder = tmp_path / f"o{o}"
        folder.mkdir()
        im = Image.new("RGB", (4, 3))
        ex = im.getexif()
        ex[0x0112] = o
        for name in cup.image_names:
            im.save(folder / name, exif=ex.tobytes())
        est = U.scene_upright(SimpleNamespace(image_dir=str(folder), image_names=cup.image_names, cameras=cup.cameras))
        assert est.sideways == 0                                         # known, not guessed
        ups[o] = est.up
    assert _deg(ups[6], plain.up) < 1e-6
    assert _deg(ups[8], -plain.up) < 1e-6
