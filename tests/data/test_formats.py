"""Format round trips and bad-input handling on small synthetic folders made in tmp_path.

The procedural scene (known cameras) is written out as COLMAP text, transforms.json
(OpenGL axes), and LLFF poses_bounds.npy; loading must give the same cameras back.
Every kind of bad input named in issue 4 must give a one-line SceneError naming the
file (or, where safe, a warning and a skip).
"""

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scenes import child_env

from tsplus_wgpu.data import SceneError, load_procedural, load_scene
from tsplus_wgpu.data.images import write_image
from tsplus_wgpu.data.undistort import ColmapUndistorter, OpenCVUndistorter
from tsplus_wgpu.types import Camera

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def tiny():
    return load_procedural("tiny", seed=3, point_noise=0.0)


@pytest.fixture(scope="module")
def tiny2(tiny):
    """The tiny scene at twice its size (128x96): a downscale by 2 still leaves >= 32 px images."""
    from types import SimpleNamespace

    from tsplus_wgpu.data.images import resize_area
    return SimpleNamespace(cameras=[c.scaled(2.0) for c in tiny.cameras],
                           images=[resize_area(im, 128, 96) for im in tiny.images],
                           points=tiny.points, point_colors=tiny.point_colors)


def write_colmap_text(root: Path, scene, n_points=200, model="PINHOLE", params=None):
    """COLMAP text model (classic 3-file layout) + images/ for a procedural scene."""
    import pycolmap
    (root / "images").mkdir(parents=True, exist_ok=True)
    sparse = root / "sparse" / "0"
    sparse.mkdir(parents=True, exist_ok=True)
    rec = pycolmap.Reconstruction()
    c = scene.cameras[0]
    cam = pycolmap.Camera.create_from_model_name(1, "PINHOLE", c.fx, c.width, c.height)
    cam.params = [c.fx, c.fy, c.cx, c.cy]
    rec.add_camera_with_trivial_rig(cam)
    for i, (c, img) in enumerate(zip(scene.cameras, scene.images)):
        name = f"view_{i:02d}.png"
        write_image(root / "images" / name, img)
        rec.add_image_with_trivial_frame(pycolmap.Image(name=name, camera_id=1, image_id=i + 1),
                                         pycolmap.Rigid3d(c.world_to_camera[:3, :4]))
    for p, col in zip(scene.points[:n_points], scene.point_colors[:n_points]):
        rec.add_point3D(p, pycolmap.Track(), (col * 255).astype(np.uint8))
    rec.write_text(str(sparse))
    for extra in ("rigs.txt", "frames.txt"):  # classic COLMAP 3.x layout
        (sparse / extra).unlink(missing_ok=True)
    if model != "PINHOLE":
        lines = (sparse / "cameras.txt").read_text().splitlines()
        lines[-1] = f"1 {model} {c.width} {c.height} " + " ".join(str(v) for v in params)
        (sparse / "cameras.txt").write_text("\n".join(lines) + "\n")
    return sparse


def write_transforms(root: Path, scene, extra=None, frame_extra=None):
    (root / "images").mkdir(parents=True, exist_ok=True)
    c0 = scene.cameras[0]
    frames = []
    for i, (c, img) in enumerate(zip(scene.cameras, scene.images)):
        write_image(root / "images" / f"{i:04d}.png", img)
        c2w = np.linalg.inv(c.world_to_camera) @ np.diag([1.0, -1.0, -1.0, 1.0])  # OpenCV -> OpenGL
        fr = {"file_path": f"images/{i:04d}.png", "transform_matrix": c2w.tolist()}
        if frame_extra and i in frame_extra:
            fr.update(frame_extra[i])
        frames.append(fr)
    data = {"fl_x": c0.fx, "fl_y": c0.fy, "cx": c0.cx, "cy": c0.cy, "w": c0.width, "h": c0.height,
            "frames": frames}
    data.update(extra or {})
    (root / "transforms.json").write_text(json.dumps(data))
    return root / "transforms.json"


def write_llff(root: Path, scene):
    (root / "images").mkdir(parents=True, exist_ok=True)
    rows = []
    for i, (c, img) in enumerate(zip(scene.cameras, scene.images)):
        write_image(root / "images" / f"img_{i:03d}.png", img)
        c2w = np.linalg.inv(c.world_to_camera)
        # OpenCV (right, down, forward) -> LLFF (down, right, back)
        m = np.stack([c2w[:3, 1], c2w[:3, 0], -c2w[:3, 2], c2w[:3, 3], [c.height, c.width, c.fx]], 1)
        rows.append(np.concatenate([m.reshape(-1), [0.5, 8.0]]))
    np.save(root / "poses_bounds.npy", np.array(rows))


def assert_same_cameras(a, b, tol=1e-6):
    assert len(a) == len(b)
    for ca, cb in zip(a, b):
        assert (ca.width, ca.height) == (cb.width, cb.height)
        np.testing.assert_allclose([ca.fx, ca.fy, ca.cx, ca.cy], [cb.fx, cb.fy, cb.cx, cb.cy], atol=tol)
        np.testing.assert_allclose(ca.world_to_camera, cb.world_to_camera, atol=tol)


# --------------------------------------------------------------------------- round trips
def test_colmap_text_round_trip(tmp_path, tiny):
    write_colmap_text(tmp_path, tiny)
    sc = load_scene(tmp_path)
    assert sc.format == "colmap" and sc.points_source == "sfm" and len(sc.points) == 200
    assert_same_cameras(sc.cameras, tiny.cameras)
    np.testing.assert_allclose(sc.images[1], tiny.images[1], atol=1 / 255)
    assert sc.test_indices == [0] and sc.train_indices == list(range(1, 8))


def test_transforms_round_trip_opengl_axes(tmp_path, tiny):
    write_transforms(tmp_path, tiny)
    sc = load_scene(tmp_path, points="none")
    assert sc.format == "transforms"
    assert_same_cameras(sc.cameras, tiny.cameras)


def test_transforms_camera_angle_and_frame_override(tmp_path, tiny):
    c0 = tiny.cameras[0]
    write_transforms(tmp_path, tiny, extra={"fl_x": None, "fl_y": None, "cx": None, "cy": None,
                                            "camera_angle_x": 2 * math.atan(c0.width / (2 * c0.fx))},
                     frame_extra={2: {"fl_x": 60.0, "fl_y": 61.0}})
    sc = load_scene(tmp_path, points="none")
    assert abs(sc.cameras[0].fx - c0.fx) < 1e-6 and abs(sc.cameras[0].cx - c0.width / 2) < 1e-9
    assert sc.cameras[2].fx == 60.0 and sc.cameras[2].fy == 61.0


def test_llff_round_trip_and_split(tmp_path, tiny):
    write_llff(tmp_path, tiny)
    sc = load_scene(tmp_path, points="frusta")
    assert sc.format == "llff" and sc.points_source == "frusta" and len(sc.points) > 100
    assert_same_cameras(sc.cameras, tiny.cameras)
    assert sc.test_indices == [0]
    assert any("frusta" in w for w in sc.warnings)


def test_downscale_scales_intrinsics(tmp_path, tiny2):
    write_colmap_text(tmp_path, tiny2)
    sc = load_scene(tmp_path, downscale=2)
    c, c0 = sc.cameras[0], tiny2.cameras[0]
    assert (c.width, c.height) == (64, 48)
    np.testing.assert_allclose([c.fx, c.cx, c.cy], [c0.fx / 2, c0.cx / 2, c0.cy / 2])


def test_images_n_folder_used_for_downscale(tmp_path, tiny2):
    write_colmap_text(tmp_path, tiny2)
    (tmp_path / "images_2").mkdir()
    for i, img in enumerate(tiny2.images):
        write_image(tmp_path / "images_2" / f"view_{i:02d}.png", img[::2, ::2])
    sc = load_scene(tmp_path, downscale=2)
    assert sc.cameras[0].width == 64 and abs(sc.cameras[0].fx - tiny2.cameras[0].fx / 2) < 1e-9
    np.testing.assert_allclose(sc.images[3], tiny2.images[3][::2, ::2], atol=1 / 255)
    assert sc.image_dir == str(tmp_path / "images_2") and "1/2 size" in sc.summary()


def test_split_none_and_every_k(tmp_path, tiny):
    write_colmap_text(tmp_path, tiny)
    assert load_scene(tmp_path, split="none").test_indices == []
    assert load_scene(tmp_path, split="every4").test_indices == [0, 4]


def test_rgba_composited_on_background(tmp_path, tiny):
    write_transforms(tmp_path, tiny)
    import cv2
    rgba = np.zeros((tiny.cameras[0].height, tiny.cameras[0].width, 4), np.uint8)
    rgba[..., 2] = 255  # red in BGR(A) order, fully transparent except the top half
    rgba[: rgba.shape[0] // 2, :, 3] = 255
    cv2.imwrite(str(tmp_path / "images" / "0001.png"), rgba)
    sc = load_scene(tmp_path, background="white", points="none")
    img = sc.images[1]
    np.testing.assert_allclose(img[0, 0], [1, 0, 0], atol=1e-6)
    np.testing.assert_allclose(img[-1, -1], [1, 1, 1], atol=1e-6)
    assert img.dtype == np.float32 and img.shape[2] == 3


# --------------------------------------------------------------------------- undistortion
def _distort(xn, yn, k1, k2, p1, p2):
    r2 = xn * xn + yn * yn
    radial = 1 + k1 * r2 + k2 * r2 * r2
    return (xn * radial + 2 * p1 * xn * yn + p2 * (r2 + 2 * xn * xn),
            yn * radial + p1 * (r2 + 2 * yn * yn) + 2 * p2 * xn * yn)


@pytest.mark.parametrize("backend", ["opencv", "colmap"])
def test_undistortion_matches_the_distortion_formula(backend):
    """Undistorting a distorted smooth image gives what the pinhole camera sees (formula check)."""
    import pycolmap
    W, H, f, cx, cy = 200, 150, 160.0, 101.3, 74.1
    k = (0.08, -0.03, 0.002, -0.001)
    pattern = lambda x, y: 0.5 + 0.25 * np.sin(7 * x + 2) * np.cos(5 * y - 1) + 0.2 * x  # noqa: E731
    jj, ii = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    # distorted image: a pixel's undistorted ray is found by inverting the distortion (fixed point)
    xd, yd = (jj - cx) / f, (ii - cy) / f
    xu, yu = xd.copy(), yd.copy()
    for _ in range(50):
        dx, dy = _distort(xu, yu, *k)
        xu, yu = xu + (xd - dx), yu + (yd - dy)
    img = np.repeat(pattern(xu, yu)[..., None], 3, 2).astype(np.float32)
    cam = Camera(W, H, f, f, cx, cy, np.eye(4))
    if backend == "opencv":
        out, ucam = OpenCVUndistorter(k)(img, cam)
    else:
        pc = pycolmap.Camera.create_from_model_name(1, "OPENCV", f, W, H)
        pc.params = [f, f, cx, cy, *k]
        out, ucam = ColmapUndistorter(pc)(img, cam)
    ju, iu = np.meshgrid(np.arange(ucam.width) + 0.5, np.arange(ucam.height) + 0.5)
    expect = pattern((ju - ucam.cx) / ucam.fx, (iu - ucam.cy) / ucam.fy)
    err = np.abs(out[..., 0] - expect)[3:-3, 3:-3]
    assert err.mean() < 2e-3 and err.max() < 2e-2, (err.mean(), err.max())


def test_colmap_non_pinhole_model_is_undistorted(tmp_path, tiny):
    c = tiny.cameras[0]
    write_colmap_text(tmp_path, tiny, model="OPENCV", params=[c.fx, c.fy, c.cx, c.cy, 0.05, -0.01, 0.001, 0.0])
    sc = load_scene(tmp_path)
    assert sc.camera_models == {"OPENCV": 8}
    assert all(np.isfinite(im).all() for im in sc.images)
    u = sc.cameras[0]  # pycolmap keeps the focal length and crops to the valid region
    assert (u.width, u.height, u.cx) != (c.width, c.height, c.cx)
    assert sc.images[0].shape[:2] == (u.height, u.width)


# --------------------------------------------------------------------------- bad input
def test_missing_image_is_skipped_with_warning_or_error_when_strict(tmp_path, tiny):
    write_colmap_text(tmp_path, tiny)
    (tmp_path / "images" / "view_03.png").unlink()
    sc = load_scene(tmp_path)
    assert len(sc.images) == 7 and sc.skipped == [("view_03.png", "missing")]
    assert any("view_03.png" in w for w in sc.warnings) and "skipped" in sc.summary()
    assert 3 not in [sc.image_names.index(n) for n in sc.image_names if n == "view_03.png"]
    with pytest.raises(SceneError, match=r"view_03\.png.*not found"):
        load_scene(tmp_path, on_bad_image="error")


def test_corrupt_image_is_skipped_or_error(tmp_path, tiny):
    write_colmap_text(tmp_path, tiny)
    (tmp_path / "images" / "view_05.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage " * 10)
    (tmp_path / "images" / "view_06.png").write_bytes(b"")
    sc = load_scene(tmp_path)
    assert {n for n, _ in sc.skipped} == {"view_05.png", "view_06.png"}
    with pytest.raises(SceneError, match=r"view_05\.png.*corrupt"):
        load_scene(tmp_path, on_bad_image="error")


def test_all_images_unreadable_is_an_error(tmp_path, tiny):
    write_colmap_text(tmp_path, tiny)
    for p in (tmp_path / "images").iterdir():
        p.write_bytes(b"not an image")
    with pytest.raises(SceneError, match="none of the 8 images"):
        load_scene(tmp_path)


def test_unreadable_permissions(tmp_path, tiny, monkeypatch):
    write_colmap_text(tmp_path, tiny)
    target = tmp_path / "images" / "view_02.png"
    target.chmod(0)
    if os.geteuid() == 0:
        # root reads anything: make the permission check answer as it would for a user
        from tsplus_wgpu.data import images as images_mod
        real_access = os.access
        monkeypatch.setattr(images_mod.os, "access",
                            lambda p, mode, *a, **k: False if os.fspath(p) == os.fspath(target) else real_access(p, mode, *a, **k))
    with pytest.raises(SceneError, match="not readable"):
        load_scene(tmp_path, on_bad_image="error")


def test_mixed_image_sizes_in_one_camera(tmp_path, tiny):
    write_colmap_text(tmp_path, tiny)
    write_image(tmp_path / "images" / "view_04.png", np.zeros((40, 64, 3)))
    with pytest.raises(SceneError, match=r"view_04\.png.*64x40"):
        load_scene(tmp_path)


def test_mixed_image_sizes_transforms(tmp_path, tiny):
    write_transforms(tmp_path, tiny, extra={"w": None, "h": None})
    write_image(tmp_path / "images" / "0002.png", np.zeros((24, 32, 3)))
    with pytest.raises(SceneError, match=r"0002\.png.*32x24"):
        load_scene(tmp_path, points="none")


def test_empty_folder(tmp_path):
    with pytest.raises(SceneError, match="empty"):
        load_scene(tmp_path)


def test_missing_path_and_unknown_folder(tmp_path):
    with pytest.raises(SceneError, match="no such file"):
        load_scene(tmp_path / "nope")
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(SceneError, match="no photos and no camera model in it.*; point to a scene folder"):
        load_scene(tmp_path)


def test_a_folder_without_a_scene_points_at_what_it_holds(tmp_path, tiny):
    """A phone's DCIM folder (photos two levels down), several photo folders, a folder of scenes,
    a video (a Mac's hidden ``._`` copy ignored): the error names where the photos, scenes or the
    video are, instead of only saying there is no scene."""
    from tsplus_wgpu.data import detect_format
    from tsplus_wgpu.data.images import write_image
    one = tmp_path / "DCIM" / "100APPLE"
    one.mkdir(parents=True)
    for i in range(3):
        write_image(one / f"IMG_{i}.jpg", np.full((8, 8, 3), 0.5))
    (tmp_path / "DCIM" / "100APPLE" / "IMG_9.HEIC").write_bytes(b"x")
    for call in (load_scene, detect_format):
        with pytest.raises(SceneError, match=rf"; its subfolder DCIM/100APPLE holds 4 photos: pass {one}$"):
            call(tmp_path)
    two = tmp_path / "DCIM" / "101APPLE"
    two.mkdir()
    write_image(two / "IMG_5.png", np.full((8, 8, 3), 0.5))
    with pytest.raises(SceneError, match=r"its subfolders hold 100APPLE \(4 photos\), 101APPLE \(1 photo\): pass"):
        load_scene(tmp_path / "DCIM")
    (tmp_path / "._walk.MOV").write_bytes(b"x")
    (tmp_path / "walk.MOV").write_bytes(b"x")
    with pytest.raises(SceneError, match=r"it holds a video: pass the video file itself \(.*/walk\.MOV\); or its sub"):
        load_scene(tmp_path)
    scenes = tmp_path / "datasets"                       # scene folders: the scene, not its images/
    write_colmap_text(scenes / "cup", tiny)
    with pytest.raises(SceneError, match=rf"its subfolder cup holds a scene: pass {scenes / 'cup'}$"):
        load_scene(scenes)



def test_zero_points_falls_back_with_warning(tmp_path, tiny):
    write_colmap_text(tmp_path, tiny, n_points=0)
    sc = load_scene(tmp_path, points="frusta")
    assert sc.points_source == "frusta" and len(sc.points) > 0
    assert any("points3D.txt has no points" in w for w in sc.warnings)


def test_zero_registered_images(tmp_path, tiny):
    sparse = write_colmap_text(tmp_path, tiny)
    lines = (sparse / "images.txt").read_text().splitlines()
    (sparse / "images.txt").write_text("\n".join(ln for ln in lines if ln.startswith("#")) + "\n")
    with pytest.raises(SceneError, match=r"images\.txt.*no registered images"):
        load_scene(tmp_path)


def test_non_finite_pose_colmap(tmp_path, tiny):
    sparse = write_colmap_text(tmp_path, tiny)
    lines = (sparse / "images.txt").read_text().splitlines()
    for k, ln in enumerate(lines):
        if ln.endswith("view_02.png"):
            parts = ln.split()
            parts[5] = "nan"
            lines[k] = " ".join(parts)
    (sparse / "images.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(SceneError, match=r"view_02\.png.*non-finite"):
        load_scene(tmp_path)


def test_non_finite_pose_transforms_and_llff(tmp_path, tiny):
    write_transforms(tmp_path / "t", tiny, frame_extra={1: {"transform_matrix": [[float("nan")] * 4] * 4}})
    with pytest.raises(SceneError, match=r"transforms\.json \(frame 1\).*non-finite"):
        load_scene(tmp_path / "t")
    write_llff(tmp_path / "l", tiny)
    arr = np.load(tmp_path / "l" / "poses_bounds.npy")
    arr[2, 3] = np.inf
    np.save(tmp_path / "l" / "poses_bounds.npy", arr)
    with pytest.raises(SceneError, match=r"poses_bounds\.npy \(row 2.*non-finite"):
        load_scene(tmp_path / "l")


def test_unknown_camera_model(tmp_path, tiny):
    sparse = write_colmap_text(tmp_path / "c", tiny)
    txt = (sparse / "cameras.txt").read_text().replace(" PINHOLE ", " MY_LENS ")
    (sparse / "cameras.txt").write_text(txt)
    with pytest.raises(SceneError, match=r"cameras\.txt.*unknown camera model 'MY_LENS'"):
        load_scene(tmp_path / "c")
    write_transforms(tmp_path / "t", tiny, extra={"camera_model": "EQUIRECTANGULAR"})
    with pytest.raises(SceneError, match="unknown camera_model 'EQUIRECTANGULAR'"):
        load_scene(tmp_path / "t")


def test_invalid_transforms_json(tmp_path):
    (tmp_path / "transforms.json").write_text("{ not json")
    with pytest.raises(SceneError, match=r"transforms\.json: invalid JSON"):
        load_scene(tmp_path)


def test_llff_pose_count_mismatch(tmp_path, tiny):
    write_llff(tmp_path, tiny)
    (tmp_path / "images" / "img_000.png").unlink()
    with pytest.raises(SceneError, match="8 poses but 7 images"):
        load_scene(tmp_path)


def test_photos_too_few(tmp_path):
    for i in range(2):
        write_image(tmp_path / f"p{i}.png", np.random.default_rng(i).random((60, 80, 3)))
    with pytest.raises(SceneError, match="at least 3"):
        load_scene(tmp_path)


def test_photos_sfm_registers_too_few(tmp_path):
    rng = np.random.default_rng(0)
    for i in range(5):  # unrelated noise images: nothing to match
        write_image(tmp_path / f"noise_{i}.png", rng.random((120, 160, 3)))
    with pytest.raises(SceneError, match="registered only"):
        load_scene(tmp_path, cache_dir=tmp_path / "cache")


def test_cli_prints_one_line_and_exits_2(tmp_path):
    env = child_env(REPO)
    r = subprocess.run([sys.executable, "-m", "tsplus_wgpu.cli.inspect", str(tmp_path), "--quiet"],
                       capture_output=True, text=True, env=env, cwd=REPO)
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and "Traceback" not in r.stderr
    assert str(tmp_path) in r.stderr and "empty" in r.stderr


def test_cli_inspect_procedural():
    env = child_env(REPO)
    r = subprocess.run([sys.executable, "-m", "tsplus_wgpu.cli.inspect", "procedural:tiny", "--quiet"],
                       capture_output=True, text=True, env=env, cwd=REPO)
    assert r.returncode == 0, r.stderr
    for word in ("format:", "cameras:", "images:", "points:", "split:", "warnings:"):
        assert word in r.stdout


def test_cli_parser_registration():
    import argparse
    from tsplus_wgpu.cli.inspect import add_parser, run
    p = argparse.ArgumentParser(prog="tsplus")
    add_parser(p.add_subparsers(dest="command"))
    args = p.parse_args(["inspect", "procedural:tiny", "--split", "none", "--quiet"])
    assert args.func is run and args.split == "none"


def test_exif_orientation_is_ignored_as_colmap_ignores_it(tmp_path):
    """Phone photos taken upright are often stored sideways with an EXIF orientation tag.
    COLMAP (pycolmap) calibrates and poses the pixel grid as stored, so the loader must read
    that grid too: a rotated image would not match its camera."""
    from PIL import Image
    from tsplus_wgpu.data.images import read_image_raw, read_image_size
    from tsplus_wgpu.data.sfm import _pycolmap
    rng = np.random.default_rng(0)
    stored = (rng.uniform(0, 1, (90, 160, 3)) * 255).astype(np.uint8)
    stored[:30, :50] = 255                                   # a bright corner at the stored top left
    folder = tmp_path / "photos"
    folder.mkdir()
    im = Image.fromarray(stored)
    exif = im.getexif()
    exif[0x0112] = 6                                         # "rotate 90 degrees clockwise to view"
    im.save(folder / "p.jpg", exif=exif.tobytes(), quality=95)
    with Image.open(folder / "p.jpg") as check:
        assert check.getexif().get(0x0112) == 6
    img = read_image_raw(folder / "p.jpg")
    assert img.shape == (90, 160, 3) and read_image_size(folder / "p.jpg") == (160, 90)
    assert img[:30, :50].mean() > 0.95 and img[-30:, -50:].mean() < 0.8
    pycolmap = _pycolmap()
    pycolmap.extract_features(tmp_path / "db.db", folder, camera_mode=pycolmap.CameraMode.PER_IMAGE)
    db = pycolmap.Database.open(str(tmp_path / "db.db"))
    cams = db.read_all_cameras()
    assert [(c.width, c.height) for c in cams] == [(160, 90)]
