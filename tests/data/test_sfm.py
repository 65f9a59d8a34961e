"""Photos-only input: pycolmap SfM on a small downscaled subset of the cup capture must recover
poses consistent with the given COLMAP model (relative rotation error < 2 degrees), the same
poses and points on every run.

Marked ``slow`` so it can be deselected with ``-m "not slow"``; it runs by default (~5 s here).
"""

import os
from pathlib import Path

import numpy as np
import pytest

from tsplus_wgpu.data import SceneError, load_scene
from tsplus_wgpu.data.images import resize_area, write_image

DATA = Path(os.environ.get("TSPLUS_DATA", Path(__file__).resolve().parents[3] / "shared" / "data"))


def rotation_angle_deg(R):
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))


@pytest.mark.slow
def test_photos_only_sfm_recovers_cup_poses(tmp_path, monkeypatch):
    if not (DATA / "cup").is_dir():
        pytest.skip(f"shared data scene {DATA / 'cup'} not found (set TSPLUS_DATA)")
    monkeypatch.delenv("TSPLUS_SFM_THREADS", raising=False)     # the default (one thread) is what repeats
    ref = load_scene(DATA / "cup", split="none", points="none")
    centres = np.stack([c.center for c in ref.cameras])
    i0 = ref.image_names.index("1.jpg")
    chosen = np.argsort(np.linalg.norm(centres - centres[i0], axis=1))[:10]  # 10 neighbouring photos
    photos = tmp_path / "photos"
    photos.mkdir()
    for i in chosen:
        write_image(photos / ref.image_names[i], resize_area(ref.images[i], 400, 300))
    sc = load_scene(photos, split="none", cache_dir=tmp_path / "cache")
    assert sc.format == "photos" and sc.points_source == "sfm" and len(sc.points) > 300
    assert len(sc.cameras) >= 8
    by_name = {n: c for n, c in zip(ref.image_names, ref.cameras)}
    errs = []
    for a in range(len(sc.cameras)):
        for b in range(a + 1, len(sc.cameras)):
            rel = sc.cameras[a].R @ sc.cameras[b].R.T
            rel_ref = by_name[sc.image_names[a]].R @ by_name[sc.image_names[b]].R.T
            errs.append(rotation_angle_deg(rel @ rel_ref.T))
    print(f"photos-only SfM: {len(sc.cameras)}/10 registered, relative rotation error "
          f"mean {np.mean(errs):.3f} max {np.max(errs):.3f} deg")
    assert max(errs) < 2.0
    again = load_scene(photos, split="none", cache_dir=tmp_path / "cache")
    assert any("reused cached SfM model" in w for w in again.warnings)
    assert np.array_equal(again.points, sc.points)
    fresh = load_scene(photos, split="none", cache_dir=tmp_path / "cache2")   # from scratch: the same bits
    assert not any("reused cached SfM model" in w for w in fresh.warnings)
    assert np.array_equal(fresh.points, sc.points) and fresh.image_names == sc.image_names
    assert all(np.array_equal(a.world_to_camera, b.world_to_camera) for a, b in zip(fresh.cameras, sc.cameras))


@pytest.mark.slow
def test_photos_only_sfm_of_a_tiny_unmatchable_set(tmp_path):
    rng = np.random.default_rng(1)
    for i in range(4):
        write_image(tmp_path / f"flat_{i}.png", np.full((90, 120, 3), 0.3 + 0.1 * i) + 0.01 * rng.random((90, 120, 3)))
    with pytest.raises(SceneError, match=r"registered only 0 of 4 photos|SfM failed"):
        load_scene(tmp_path, cache_dir=tmp_path / "cache")
