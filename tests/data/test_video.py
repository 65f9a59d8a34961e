"""A video as a scene (:mod:`tsplus_wgpu.data.video`): the sharpest frame of each window is kept,
the frames are cached by the video's bytes, bad videos are one-line errors, and the frames of a
real capture go through SfM matched in time order to the poses of the capture's COLMAP model."""

import json
import os
from pathlib import Path

import numpy as np
import pytest

from tsplus_wgpu.data import SceneError, detect_format, load_scene
from tsplus_wgpu.data import loader
from tsplus_wgpu.data import photos as photos_mod
from tsplus_wgpu.data.images import resize_area
from tsplus_wgpu.data.video import (MANIFEST, SCORE_SIZE, choose_frames, extract_frames, sharpness,
                                    video_frames_dir)

cv2 = pytest.importorskip("cv2")


def write_video(path, frames, fps=10, codec="mp4v"):
    """``frames`` (uint8 BGR, one size) as a video (MPEG-4 part 2, or FFV1 in .mkv); skips when
    OpenCV cannot write one."""
    h, w = frames[0].shape[:2]
    out = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*codec), fps, (w, h))
    if not out.isOpened():
        pytest.skip(f"this OpenCV cannot write {codec} video")
    for f in frames:
        out.write(np.ascontiguousarray(f))
    out.release()
    return path


def texture(seed, h=120, w=160):
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 256, (h // 8, w // 8, 3)).astype(np.uint8)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_NEAREST)


def test_choose_frames_keeps_the_sharpest_of_each_window():
    scores = [1, 5, 2, 9, 0, 3, 3, 1, 8, 4]
    assert choose_frames(scores, 5) == [1, 3, 5, 6, 8]          # windows [0,2) [2,4) [4,6) [6,8) [8,10)
    assert choose_frames(scores, 3) == [1, 3, 8]                # [0,3) [3,6) [6,10)
    assert choose_frames(scores, 10) == list(range(10))
    assert choose_frames(scores, 50) == list(range(10))         # fewer frames than asked: all of them
    assert choose_frames([2, 2, 2, 2], 2) == [0, 2]             # a tie keeps the first
    assert choose_frames([], 4) == []
    rng = np.random.default_rng(0)
    for n, k in [(7, 3), (100, 13), (31, 31), (1000, 100)]:
        s = rng.random(n)
        got = choose_frames(s, k)
        assert len(got) == min(n, k) and got == sorted(got) and len(set(got)) == len(got)
        bounds = (np.arange(k + 1) * n) // k                      # brute force: the best of each window
        assert got == [a + int(np.argmax(s[a:b])) for a, b in zip(bounds[:-1], bounds[1:])]


def test_sharpness_ranks_blur_and_ignores_the_resolution():
    img = texture(1, 300, 400)
    sharp = sharpness(img)
    blurred = [sharpness(cv2.GaussianBlur(img, (0, 0), s)) for s in (0.8, 1.5, 3.0)]
    assert sharp > blurred[0] > blurred[1] > blurred[2] > 0
    assert sharpness(np.full((50, 60, 3), 77, np.uint8)) == 0.0
    # twice the size, each pixel a 2x2 block: shrunk by blocks of 2 to the same grey image
    big = np.repeat(np.repeat(img, 2, axis=0), 2, axis=1)
    assert max(big.shape[:2]) > SCORE_SIZE >= max(img.shape[:2])
    assert sharpness(big) == pytest.approx(sharp, rel=1e-12)
    # the 5-point Laplacian's variance in float64 of OpenCV's grey image, by hand on a small frame
    f = texture(2, 12, 16)
    g = cv2.cvtColor(f, cv2.COLOR_BGR2GRAY).astype(np.float64)
    assert np.abs(g - f.astype(np.float64) @ [0.114, 0.587, 0.299]).max() <= 0.5 + 1e-9     # luma, rounded
    lap = [g[y - 1, x] + g[y + 1, x] + g[y, x - 1] + g[y, x + 1] - 4 * g[y, x]
           for y in range(1, 11) for x in range(1, 15)]
    assert sharpness(f) == pytest.approx(np.var(lap), rel=1e-12)


@pytest.fixture(scope="module")
def blurry_video(tmp_path_factory):
    """30 frames: in each run of three, one sharp frame between two blurred ones (at 0, 1 or 2)."""
    frames, sharp_at = [], []
    for k in range(10):
        img = texture(10 + k)
        j = k % 3
        sharp_at.append(3 * k + j)
        frames += [img if i == j else cv2.GaussianBlur(img, (0, 0), 2.5) for i in range(3)]
    path = write_video(tmp_path_factory.mktemp("video") / "walk.mp4", frames)
    return path, sharp_at


def test_extract_frames_writes_the_sharp_ones_in_order(blurry_video, tmp_path):
    video, sharp_at = blurry_video
    m = extract_frames(video, tmp_path / "frames", count=10)
    assert m["frames_decoded"] == 30 and m["indices"] == sharp_at
    names = sorted(p.name for p in (tmp_path / "frames").iterdir() if p.suffix == ".jpg")
    assert names == [f"frame_{i:06d}.jpg" for i in sharp_at] == m["frames"]
    assert json.loads((tmp_path / "frames" / MANIFEST).read_text())["indices"] == sharp_at
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]      # no temporary folder left
    m5 = extract_frames(video, tmp_path / "five", count=5)                    # windows of 6: two sharp frames each
    assert len(m5["frames"]) == 5 and set(m5["indices"]) <= set(sharp_at)


def test_video_frames_are_cached_by_content(blurry_video, tmp_path):
    video, sharp_at = blurry_video
    warn = []
    d = video_frames_dir(video, cache=tmp_path / "cache", count=10, warnings=warn)
    assert not warn and sorted(p.name for p in d.glob("*.jpg")) == [f"frame_{i:06d}.jpg" for i in sharp_at]
    copy = tmp_path / "copy.mp4"
    copy.write_bytes(video.read_bytes())
    warn = []
    assert video_frames_dir(copy, cache=tmp_path / "cache", count=10, warnings=warn) == d   # same bytes: reused
    assert any("reused cached frames" in w for w in warn)
    assert video_frames_dir(copy, cache=tmp_path / "cache", count=5) != d
    # a video as a scene argument: its DEFAULT_FRAMES (100) sharpest frames, here all 30
    every = loader._scene_root(video, tmp_path / "cache", False, [])
    assert len(list(every.glob("*.jpg"))) == 30 and every.parent.parent == tmp_path / "cache"
    assert detect_format(video) == "video" and detect_format(d) == "video"


def test_bad_videos_are_one_line_errors(tmp_path, blurry_video):
    junk = tmp_path / "junk.mp4"
    junk.write_bytes(os.urandom(5000))
    with pytest.raises(SceneError, match=r"junk\.mp4: cannot be read as a video") as e:
        load_scene(junk, cache_dir=tmp_path / "cache")
    assert "\n" not in str(e.value)
    short = write_video(tmp_path / "short.mp4", [texture(3), texture(4)])
    with pytest.raises(SceneError, match=r"short\.mp4: 2 frame\(s\) decoded, SfM needs at least 3"):
        load_scene(short, cache_dir=tmp_path / "cache")
    assert not list((tmp_path / "cache").glob("video_*"))   # nothing half made left in the cache
    with pytest.raises(SceneError, match="at least 3 frames"):
        extract_frames(blurry_video[0], tmp_path / "f", count=2)
    assert not (tmp_path / "f").exists()
    other = tmp_path / "notes.txt"
    other.write_text("x")
    with pytest.raises(SceneError, match=r"notes\.txt: not a scene folder or a video"):
        load_scene(other)


def rotation_angle_deg(R):
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))


@pytest.mark.slow
def test_a_video_of_the_cup_registers_in_time_order(tmp_path, monkeypatch, cup_near):
    """The cup's 12 photos nearest photo 1, ordered along the camera path, as a video in which
    each is followed by a blurred copy: the 12 sharp frames are kept, SfM matches them in time
    order and recovers the COLMAP model's relative rotations within 2 degrees (0.21 mean, 0.52
    max here; the photos themselves, every pair matched: 0.22 / 0.54). FFV1, not MPEG-4 part 2:
    at OpenCV's bitrate for it, 400x300 frames come back at 37.8 dB and their compression
    artefacts give SfM 1.5 / 3.7 degrees (either matching)."""
    ref, near = cup_near
    centres = np.stack([c.center for c in ref.cameras])
    near = near[:12]
    order = [int(near[0])]                                    # walk: always to the nearest photo not yet shown
    while len(order) < len(near):
        rest = [int(i) for i in near if int(i) not in order]
        order.append(min(rest, key=lambda i: np.linalg.norm(centres[i] - centres[order[-1]])))
    frames = []
    for i in order:
        bgr = np.ascontiguousarray((resize_area(ref.images[i], 400, 300)[..., ::-1] * 255 + 0.5).astype(np.uint8))
        frames += [bgr, cv2.GaussianBlur(bgr, (0, 0), 2.0)]
    video = write_video(tmp_path / "cup.mkv", frames, fps=5, codec="FFV1")
    seen = []
    orig = photos_mod._extract_and_match
    monkeypatch.setattr(photos_mod, "_extract_and_match", lambda *a, **k: (seen.append(k.get("sequential")), orig(*a, **k)))
    frames_dir = video_frames_dir(video, cache=tmp_path / "cache", count=12)
    assert json.loads((frames_dir / MANIFEST).read_text())["indices"] == list(range(0, 24, 2))
    sc = load_scene(frames_dir, split="none", cache_dir=tmp_path / "cache", points="none")
    assert sc.format == "video" and seen == [True] and len(sc.cameras) >= 10
    by_frame = {f"frame_{2 * k:06d}.jpg": ref.cameras[i] for k, i in enumerate(order)}
    errs = [rotation_angle_deg((sc.cameras[a].R @ sc.cameras[b].R.T) @ (by_frame[sc.image_names[a]].R
                                                                          @ by_frame[sc.image_names[b]].R.T).T)
            for a in range(len(sc.cameras)) for b in range(a + 1, len(sc.cameras))]
    print(f"video SfM: {len(sc.cameras)}/12 registered, relative rotation error mean {np.mean(errs):.3f} "
          f"max {np.max(errs):.3f} deg")
    assert max(errs) < 2.0


def test_the_frames_command(blurry_video, tmp_path, capsys):
    from tsplus_wgpu.cli.main import main
    video, sharp_at = blurry_video
    out = tmp_path / "frames"
    assert main(["frames", str(video), "--out", str(out), "--count", "10", "--no-progress"]) == 0
    assert "wrote 10 frames of walk.mp4" in capsys.readouterr().out
    assert sorted(p.name for p in out.glob("*.jpg")) == [f"frame_{i:06d}.jpg" for i in sharp_at]
    assert detect_format(out) == "video"
    assert main(["frames", str(video), "--out", str(out), "--count", "5", "--no-progress"]) == 2   # not empty
    assert "--overwrite" in capsys.readouterr().err
    assert len(list(out.glob("*.jpg"))) == 10                                                      # untouched
    assert main(["frames", str(video), "--out", str(out), "--count", "5", "--no-progress", "--overwrite"]) == 0
    assert len(list(out.glob("*.jpg"))) == 5 and not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def _portrait_source_frame(i):
    """Frame ``i`` of ``fixtures/portrait_rotate90.mp4`` as it was drawn (160x120, landscape)."""
    import cv2
    img = np.zeros((120, 160, 3), np.uint8)
    img[:] = (40, 80, 160)
    cv2.rectangle(img, (10 + i * 5, 10), (60 + i * 5, 40), (255, 255, 255), -1)
    cv2.putText(img, "UP", (70, 100), cv2.FONT_HERSHEY_SIMPLEX, 1, (0, 255, 0), 2)
    return img[:, :, ::-1].astype(np.float64) / 255.0


@pytest.mark.parametrize("tag, turn", [(270, -1), (90, 1)])
def test_a_phone_video_stored_sideways_gives_upright_frames(tmp_path, tag, turn):
    """A phone's portrait video is stored landscape with a rotation in its metadata. The fixtures
    (2,965 bytes each): 12 frames drawn by ``_portrait_source_frame``, encoded by ``ffmpeg
    -framerate 12 -i f%02d.png -c:v libx264 -pix_fmt yuv420p plain.mp4``, then tagged by ``ffmpeg
    -i plain.mp4 -c copy -metadata:s:v:0 rotate=TAG`` (ffmpeg 5.1): a display matrix of -90
    degrees for TAG 270 (what an iPhone's portrait video carries), +90 for TAG 90. The frames come
    out as players show them: 120x160, the drawing turned a quarter clockwise (270) or
    anticlockwise (90); checked once against ffmpeg's own decoding, identical."""
    from tsplus_wgpu.data.images import read_image_raw
    video = Path(__file__).parent / "fixtures" / f"portrait_rotate{tag}.mp4"
    m = extract_frames(video, tmp_path / "frames", count=3)
    assert m["frames_decoded"] == 12 and len(m["frames"]) == 3
    for name, i in zip(m["frames"], m["indices"]):
        img = read_image_raw(tmp_path / "frames" / name)
        assert img.shape == (160, 120, 3)
        src = _portrait_source_frame(i)
        shown, other = np.rot90(src, k=turn), np.rot90(src, k=-turn)
        err, err_other = np.abs(img - shown).mean(), np.abs(img - other).mean()
        assert err < 0.03 and err_other > 4 * err, (err, err_other)
