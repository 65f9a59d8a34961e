"""Corrupt and implausible scene files (issue 15): every case is one SceneError line naming the
file (and line, frame, camera or field), raised before pycolmap or any heavy work sees the data;
``images_N/`` folders are found when ``images/`` is missing; caches stay out of the scene folder;
initial points are triangulated at full size whatever the downscale.

Table-driven: each case corrupts a fresh copy of a small scene in ``tmp_path``.
"""

import json
import re
import shutil
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scenes import child_env

from tests.data.test_formats import write_colmap_text, write_llff, write_transforms
from tsplus_wgpu.data import SceneError, load_procedural, load_scene
from tsplus_wgpu.data.images import resize_area, write_image

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def tiny2():
    """The tiny procedural scene at 128x96 (a downscale by 2 keeps >= 32 px)."""
    from types import SimpleNamespace
    t = load_procedural("tiny", seed=3, point_noise=0.0)
    return SimpleNamespace(cameras=[c.scaled(2.0) for c in t.cameras],
                           images=[resize_area(im, 128, 96) for im in t.images],
                           points=t.points, point_colors=t.point_colors)


@pytest.fixture(scope="module")
def templates(tiny2, tmp_path_factory):
    """One clean copy of each format, copied per case."""
    import pycolmap
    base = tmp_path_factory.mktemp("templates")
    sparse = write_colmap_text(base / "colmap_txt", tiny2, n_points=40)
    (base / "colmap_bin" / "sparse" / "0").mkdir(parents=True)
    shutil.copytree(base / "colmap_txt" / "images", base / "colmap_bin" / "images")
    pycolmap.Reconstruction(str(sparse)).write_binary(str(base / "colmap_bin" / "sparse" / "0"))
    write_transforms(base / "transforms", tiny2)
    write_llff(base / "llff", tiny2)
    return base


def scene_copy(templates, kind, dst):
    shutil.copytree(templates / kind, dst)
    return dst


# ----------------------------------------------------------------------------- corruptions
def _bin(root, stem):
    return root / "sparse" / "0" / f"{stem}.bin"


def _txt(root, stem):
    return root / "sparse" / "0" / f"{stem}.txt"


def truncate(f, keep):
    data = f.read_bytes()
    f.write_bytes(data[:keep if keep >= 0 else len(data) + keep])


def patch_bytes(f, offset, fmt, *vals):
    data = bytearray(f.read_bytes())
    struct.pack_into(fmt, data, offset, *vals)
    f.write_bytes(bytes(data))


def edit_line(f, contains, fn):
    lines = f.read_text().splitlines()
    for k, ln in enumerate(lines):
        if not ln.startswith("#") and contains in ln:
            lines[k] = fn(ln.split())
            break
    else:
        raise AssertionError(f"no line with {contains!r} in {f}")
    f.write_text("\n".join(lines) + "\n")


def first_data_line(f, fn):
    edit_line(f, "", fn)


def set_fields(idx_vals):
    def fn(parts):
        for i, v in idx_vals.items():
            parts[i] = v
        return " ".join(parts)
    return fn


def points_bin_track_to(root, image_id):
    """Give the first point of points3D.bin a track of one observation in image ``image_id``."""
    f = _bin(root, "points3D")
    data = bytearray(f.read_bytes())
    struct.pack_into("<Q", data, 8 + 43, 1)
    f.write_bytes(bytes(data[:8 + 51]) + struct.pack("<II", image_id, 0) + bytes(data[8 + 51:]))


def cameras_bin_equirect(root):
    f = _bin(root, "cameras")
    # one camera: count, then id u32, model i32, width u64, height u64, params
    f.write_bytes(struct.pack("<QIiQQ2d", 1, 1, 17, 128, 96, 128.0, 96.0))


def transforms_edit(root, frame=None, **fields):
    f = root / "transforms.json"
    d = json.loads(f.read_text())
    target = d if frame is None else d["frames"][frame]
    for k, v in fields.items():
        if k == "t_x":
            target["transform_matrix"][0][3] = v
        else:
            target[k] = v
    f.write_text(json.dumps(d))


def llff_edit(root, row, col, value):
    arr = np.load(root / "poses_bounds.npy")
    arr[row, col] = value
    np.save(root / "poses_bounds.npy", arr)


# kind, corruption, regex the one-line error must match (None: loads; ("warn", regex): loads with that warning)
CASES = {
    # binary COLMAP: counts and sizes checked before pycolmap reads a byte
    "points3D.bin truncated": ("colmap_bin", lambda r: truncate(_bin(r, "points3D"), -30),
                               r"points3D\.bin: .*truncated"),
    "points3D.bin count 1e12": ("colmap_bin", lambda r: patch_bytes(_bin(r, "points3D"), 0, "<Q", 10 ** 12),
                                r"points3D\.bin: declares 1000000000000 points but its \d+ bytes hold at most"),
    "points3D.bin huge track": ("colmap_bin", lambda r: patch_bytes(_bin(r, "points3D"), 8 + 43, "<Q", 10 ** 15),
                                r"points3D\.bin: point \d+ declares a track of 1000000000000000"),
    "points3D.bin trailing bytes": ("colmap_bin", lambda r: _bin(r, "points3D").write_bytes(
        _bin(r, "points3D").read_bytes() + b"xx"), r"points3D\.bin: 2 unexpected bytes"),
    "points3D.bin empty": ("colmap_bin", lambda r: _bin(r, "points3D").write_bytes(b""),
                           r"points3D\.bin: 0 bytes, too short"),
    "points3D.bin unknown image": ("colmap_bin", lambda r: points_bin_track_to(r, 99),
                                   r"points3D\.bin: point 1 of the file observes image 99"),
    "points3D.bin 2D point index": ("colmap_bin", lambda r: points_bin_track_to(r, 3),
                                    r"points3D\.bin: point 1 of the file observes image 3, 2D point 0, but that image "
                                    r"has 0 2D points"),
    "images.bin truncated": ("colmap_bin", lambda r: truncate(_bin(r, "images"), -5), r"images\.bin: .*truncated"),
    "images.bin zero quaternion": ("colmap_bin", lambda r: patch_bytes(_bin(r, "images"), 12, "<4d", 0, 0, 0, 0),
                                   r"images\.bin \(image 'view_00\.png'\): the rotation quaternion is all zeros"),
    "images.bin translation 1e300": ("colmap_bin", lambda r: patch_bytes(_bin(r, "images"), 12 + 32, "<d", 1e300),
                                     r"images\.bin \(image 'view_00\.png'\): translation .* implausibly large"),
    "images.bin 2D point count": ("colmap_bin", lambda r: patch_bytes(
        _bin(r, "images"), 8 + 4 + 56 + 4 + len("view_00.png") + 1, "<Q", 10 ** 9),
        r"images\.bin: image 1 \('view_00\.png'\) declares 1000000000 2D points"),
    "cameras.bin truncated": ("colmap_bin", lambda r: truncate(_bin(r, "cameras"), -8), r"cameras\.bin: .*truncated"),
    "cameras.bin unknown model id": ("colmap_bin", lambda r: patch_bytes(_bin(r, "cameras"), 12, "<i", 99),
                                     r"cameras\.bin: camera 1 has unknown camera model id 99"),
    "cameras.bin EQUIRECTANGULAR": ("colmap_bin", cameras_bin_equirect,
                                    r"cameras\.bin: camera 1 uses the EQUIRECTANGULAR model"),
    # text COLMAP: file and line, never pycolmap's "Check failed"
    "points3D.txt cut line": ("colmap_txt", lambda r: first_data_line(_txt(r, "points3D"), lambda p: " ".join(p[:5])),
                              r"points3D\.txt:\d+: malformed point line with 5 fields"),
    "points3D.txt nan": ("colmap_txt", lambda r: first_data_line(_txt(r, "points3D"), set_fields({2: "nan"})),
                         ("warn", r"dropped 1 non-finite point\(s\) from .*points3D\.txt \(line 4\)")),
    "points3D.txt error nan": ("colmap_txt", lambda r: first_data_line(_txt(r, "points3D"), set_fields({7: "nan"})),
                               r"points3D\.txt:\d+: 'nan' is not a finite number"),
    "points3D.txt colour 300": ("colmap_txt", lambda r: first_data_line(_txt(r, "points3D"), set_fields({4: "300"})),
                                r"points3D\.txt:\d+: point \d+ has colour"),
    "points3D.txt unknown image": ("colmap_txt", lambda r: first_data_line(_txt(r, "points3D"),
                                                                            lambda p: " ".join(p + ["99", "0"])),
                                   r"points3D\.txt:\d+: point 1 observes image 99, which images\.txt does not define"),
    "images.txt no images": ("colmap_txt", lambda r: _txt(r, "images").write_text("# none\n"),
                             r"images\.txt: the model has no registered images"),
    "images.txt zero quaternion": ("colmap_txt", lambda r: edit_line(
        _txt(r, "images"), "view_02.png", set_fields({1: "0", 2: "0", 3: "0", 4: "0"})),
        r"images\.txt:\d+ \(image 'view_02\.png'\): the rotation quaternion is all zeros"),
    "images.txt translation 1e300": ("colmap_txt", lambda r: edit_line(
        _txt(r, "images"), "view_02.png", set_fields({6: "1e300"})),
        r"images\.txt:\d+ \(image 'view_02\.png'\): translation .* implausibly large"),
    "images.txt unknown camera": ("colmap_txt", lambda r: edit_line(_txt(r, "images"), "view_02.png",
                                                                    set_fields({8: "7"})),
                                  r"images\.txt:\d+ \(image 'view_02\.png'\): camera 7 is not defined"),
    "images.txt short line": ("colmap_txt", lambda r: edit_line(_txt(r, "images"), "view_02.png",
                                                                lambda p: " ".join(p[:6])),
                              r"images\.txt:\d+ .*malformed image line with 6 fields"),
    "cameras.txt EQUIRECTANGULAR": ("colmap_txt", lambda r: first_data_line(
        _txt(r, "cameras"), lambda p: f"1 EQUIRECTANGULAR {p[2]} {p[3]} {p[2]} {p[3]}"),
        r"cameras\.txt:\d+: camera 1 uses the EQUIRECTANGULAR model"),
    "cameras.txt param count": ("colmap_txt", lambda r: first_data_line(_txt(r, "cameras"), lambda p: " ".join(p[:-1])),
                                r"cameras\.txt:\d+: camera 1 \(PINHOLE\) has 3 parameters, the model takes 4"),
    "cameras.txt k1 1e6": ("colmap_txt", lambda r: first_data_line(
        _txt(r, "cameras"), lambda p: " ".join(["1", "OPENCV", *p[2:8], "1e6", "0", "0", "0"])),
        r"cameras\.txt:\d+: camera 1 \(OPENCV\) has distortion parameter 1e\+06"),
    "cameras.txt width 0": ("colmap_txt", lambda r: first_data_line(_txt(r, "cameras"), set_fields({2: "0"})),
                            r"cameras\.txt:\d+: camera 1 has width 0"),
    "cameras.txt binary junk": ("colmap_txt", lambda r: _txt(r, "cameras").write_bytes(b"\xff\xfe\x00junk"),
                                r"cameras\.txt: not a text file"),
    # transforms.json
    "file_path null": ("transforms", lambda r: transforms_edit(r, 1, file_path=None),
                       r"transforms\.json \(frame 1\): 'file_path' is None"),
    "file_path number": ("transforms", lambda r: transforms_edit(r, 2, file_path=3),
                         r"transforms\.json \(frame 2\): 'file_path' is 3"),
    "camera_angle_x 0": ("transforms", lambda r: transforms_edit(r, None, fl_x=None, fl_y=None, camera_angle_x=0),
                         r"transforms\.json \(frame 0\): 'camera_angle_x' is 0 rad"),
    "w 0": ("transforms", lambda r: transforms_edit(r, None, w=0), r"transforms\.json \(frame 0\): 'w' is 0"),
    "h negative": ("transforms", lambda r: transforms_edit(r, 3, h=-96), r"transforms\.json \(frame 3\): 'h' is -96"),
    "fl_x 0": ("transforms", lambda r: transforms_edit(r, None, fl_x=0), r"'fl_x' is 0, expected a focal length"),
    "k1 1e6": ("transforms", lambda r: transforms_edit(r, None, k1=1e6),
               r"transforms\.json \(frame 0\): distortion coefficient 'k1' = 1e\+06 is implausible"),
    "translation 1e300": ("transforms", lambda r: transforms_edit(r, 4, t_x=1e300),
                          r"transforms\.json \(frame 4\): .*implausibly large"),
    "w missing, image there": ("transforms", lambda r: transforms_edit(r, None, w=None, h=None), None),
    # LLFF
    "llff h = w = 1e9": ("llff", lambda r: (llff_edit(r, 2, 4, 1e9), llff_edit(r, 2, 9, 1e9)),
                         r"poses_bounds\.npy \(row 2, img_002\.png\): 'height \(hwf column\)' is 1e\+09"),
    "llff focal 0": ("llff", lambda r: llff_edit(r, 1, 14, 0.0), r"poses_bounds\.npy \(row 1.*'focal \(hwf column\)' is 0"),
    "llff translation 1e300": ("llff", lambda r: llff_edit(r, 0, 3, 1e300), r"poses_bounds\.npy \(row 0.*implausibly large"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_bad_input_is_one_line_naming_the_file(case, templates, tmp_path):
    kind, corrupt, pattern = CASES[case]
    root = scene_copy(templates, kind, tmp_path / "scene")
    corrupt(root)
    if pattern is None or pattern[0] == "warn":
        sc = load_scene(root, points="none")
        assert len(sc.cameras) == 8
        if pattern is not None:
            assert any(re.search(pattern[1], w) for w in sc.warnings), sc.warnings
        return
    with pytest.raises(SceneError, match=pattern) as info:
        load_scene(root, points="none")
    msg = str(info.value)
    assert "\n" not in msg and "Check failed" not in msg and str(root) in msg


def test_valid_binary_model_loads_as_the_text_one(templates):
    a = load_scene(templates / "colmap_txt")
    b = load_scene(templates / "colmap_bin")
    assert len(a.points) == len(b.points) == 40
    for ca, cb in zip(a.cameras, b.cameras):
        np.testing.assert_allclose(ca.world_to_camera, cb.world_to_camera, atol=1e-12)


def test_truncated_points3d_bin_from_the_command_line(templates, tmp_path):
    """The CLI: exit status 2, one line, no traceback, quickly (no gigabyte allocation)."""
    root = scene_copy(templates, "colmap_bin", tmp_path / "scene")
    truncate(_bin(root, "points3D"), 20)
    env = child_env(REPO)
    r = subprocess.run([sys.executable, "-m", "tsplus_wgpu.cli.inspect", str(root), "--quiet"],
                       capture_output=True, text=True, env=env, cwd=REPO, timeout=60)
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and "Traceback" not in r.stderr
    assert "points3D.bin" in r.stderr and "truncated" in r.stderr


# ----------------------------------------------------------------------------- downscale
@pytest.mark.parametrize("kind", ["colmap_txt", "transforms", "llff"])
def test_downscale_below_32_px_is_an_error(kind, templates, tmp_path):
    root = scene_copy(templates, kind, tmp_path / "scene")
    with pytest.raises(SceneError, match=r"--downscale 1000 leaves 1x1-pixel images \(from 128x96\), under 32 px; "
                                         r"use --downscale 3 or less"):
        load_scene(root, downscale=1000, points="none")
    assert load_scene(root, downscale=3, points="none").cameras[0].width == 43


# ----------------------------------------------------------------------------- images_N
def _only_images_n(root, factors, tiny2):
    names = sorted(p.name for p in (root / "images").iterdir())
    for n in factors:
        (root / f"images_{n}").mkdir()
        for name, img in zip(names, tiny2.images):
            write_image(root / f"images_{n}" / name, resize_area(img, 128 // n, 96 // n))
    shutil.rmtree(root / "images")


# kind, folders present, downscale -> folder used, image width, words in the reason
IMAGES_N = [
    ("llff", (2,), 1, "images_2", 64, "images/ is missing; images_2 is the largest available"),
    ("colmap_txt", (2, 3), 1, "images_2", 64, "images/ is missing; images_2 is the largest available"),
    ("colmap_txt", (2, 3), 3, "images_3", 42, "as --downscale 3 asks"),
    ("llff", (2,), 3, "images_2", 43, "shrunk 1.5x more for --downscale 3"),
    ("colmap_bin", (4,), 2, "images_4", 32, "smaller than --downscale 2 asks"),
]


@pytest.mark.parametrize("kind,factors,downscale,folder,width,reason", IMAGES_N)
def test_images_n_found_when_images_is_missing(kind, factors, downscale, folder, width, reason, templates, tiny2,
                                               tmp_path):
    root = scene_copy(templates, kind, tmp_path / "scene")
    _only_images_n(root, factors, tiny2)
    sc = load_scene(root, downscale=downscale, points="none")
    assert Path(sc.image_dir).name == folder and reason in sc.image_dir_reason
    assert sc.cameras[0].width == width and sc.images[0].shape[1] == width
    assert abs(sc.cameras[0].fx - tiny2.cameras[0].fx * width / 128) < 1e-6
    assert f"image dir:  {sc.image_dir} ({sc.image_dir_reason})" in sc.summary()
    if "missing" in sc.image_dir_reason:
        assert any("images/ is missing" in w for w in sc.warnings)


# ----------------------------------------------------------------------------- caches
def test_cache_goes_to_the_user_cache_not_the_scene(templates, tmp_path, monkeypatch):
    root = scene_copy(templates, "llff", tmp_path / "scene")
    before = sorted(p.name for p in root.iterdir())
    monkeypatch.delenv("TSPLUS_CACHE", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    load_scene(root, points="triangulate", progress=False)
    assert sorted(p.name for p in root.iterdir()) == before
    assert any((tmp_path / "xdg" / "tsplus_wgpu").iterdir())


def test_unwritable_user_cache_falls_back_with_a_warning(templates, tmp_path, monkeypatch):
    from tsplus_wgpu.data.sfm import cache_root
    (tmp_path / "file").write_text("")
    monkeypatch.delenv("TSPLUS_CACHE", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "file"))   # a file: no folder can be made under it
    folder, note = cache_root()
    assert "not writable" in note and str(tmp_path) not in str(folder)


def test_initial_points_do_not_depend_on_the_downscale(templates, tiny2, tmp_path, monkeypatch):
    """Triangulation reads every training image at full size, and its cache key is the same
    at every downscale (so the cached points are reused)."""
    from tsplus_wgpu.data import sfm
    calls = []

    def fake(load_one, names, key, cache_dir, progress=True, **kw):
        shapes = [load_one(i)[1].shape for i in range(len(names))]
        calls.append((key, shapes))
        return np.zeros((60, 3)), np.zeros((60, 3)), {"mean_reprojection_error": 0.5}

    monkeypatch.setattr(sfm, "triangulate_frames", fake)
    root = scene_copy(templates, "llff", tmp_path / "scene")
    (root / "images_2").mkdir()
    for p in sorted((root / "images").iterdir()):
        import cv2
        write_image(root / "images_2" / p.name, resize_area(cv2.imread(str(p))[..., ::-1] / 255.0, 64, 48))
    for ds in (1, 2, 3):
        sc = load_scene(root, downscale=ds, cache_dir=tmp_path / "cache")
        assert sc.points_source == "triangulated" and len(sc.points) == 60
    assert len({k for k, _ in calls}) == 1
    assert all(s == (96, 128, 3) for _, shapes in calls for s in shapes)
