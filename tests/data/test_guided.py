"""Matching guided by known poses (tsplus_wgpu.data.guided) against a brute-force float64 twin."""

from __future__ import annotations

import numpy as np
import pytest

from scenes import look_at_camera
from tsplus_wgpu.data import guided


def _kt(cam):
    """Intrinsics and 3x4 world-to-camera transform of a Camera."""
    K = np.array([[cam.fx, 0, cam.cx], [0, cam.fy, cam.cy], [0, 0, 1.0]])
    return K, cam.world_to_camera[:3]


def _twin(xy1, xy2, desc1, desc2, F, max_px, ratio, max_angle):
    """Every pair of features, one at a time, in float64: the definition of the matches."""
    def line_dist(Fm, p, q):
        line = Fm @ np.r_[p, 1.0]
        return abs(line @ np.r_[q, 1.0]) / np.hypot(line[0], line[1])

    def ang(u, v):
        u, v = np.asarray(u, float), np.asarray(v, float)
        return np.arccos(np.clip(u @ v / (np.linalg.norm(u) * np.linalg.norm(v)), -1, 1))

    cand = {(a, b) for a in range(len(xy1)) for b in range(len(xy2))
            if line_dist(F, xy1[a], xy2[b]) <= max_px and line_dist(F.T, xy2[b], xy1[a]) <= max_px}

    def best(i, side):
        opts = sorted((ang(desc1[a], desc2[b]), b if side == 0 else a)
                      for a, b in cand if (a if side == 0 else b) == i)
        if not opts:
            return None
        second = opts[1][0] if len(opts) > 1 else np.pi
        ok = opts[0][0] <= max_angle and opts[0][0] < ratio * second
        return opts[0][1] if ok else None

    out = []
    for a in range(len(xy1)):
        b = best(a, 0)
        if b is not None and best(b, 1) == a:
            out.append((a, b))
    return np.array(out, np.int64).reshape(-1, 2)


def _scene(rng, n_true=40, n_clutter=25):
    """Two posed cameras, features of n_true shared 3D points (noisy descriptors of one source),
    and clutter: features whose descriptors copy a true one (repeated structure) elsewhere."""
    c1 = look_at_camera(640, 480, fov_deg=65.0, eye=(0.0, 0, 0), target=(0, 0, 5))
    c2 = look_at_camera(640, 480, fov_deg=65.0, eye=(0.8, 0.1, 0.3), target=(0, 0, 5))
    (K1, T1), (K2, T2) = _kt(c1), _kt(c2)
    X = rng.uniform([-2, -1.5, 3.5], [2, 1.5, 7], (n_true, 3))
    xy1 = c1.project(X)[0] + rng.normal(0, 0.2, (n_true, 2))
    xy2 = c2.project(X)[0] + rng.normal(0, 0.2, (n_true, 2))
    base = rng.integers(0, 120, (n_true, 128))
    d1 = np.clip(base + rng.integers(-4, 5, base.shape), 0, 255)
    d2 = np.clip(base + rng.integers(-4, 5, base.shape), 0, 255)
    src = rng.integers(0, n_true, n_clutter)                   # image 2 repeats some of them
    xy2 = np.r_[xy2, rng.uniform([0, 0], [640, 480], (n_clutter, 2))]
    d2 = np.r_[d2, np.clip(base[src] + rng.integers(-4, 5, (n_clutter, 128)), 0, 255)]
    return (K1, T1, K2, T2), xy1, xy2, d1.astype(np.uint8), d2.astype(np.uint8)


def test_fundamental_holds_for_projected_points():
    rng = np.random.default_rng(1)
    (K1, T1, K2, T2), xy1, xy2, _, _ = _scene(rng, n_clutter=0)
    F = guided.fundamental(K1, T1, K2, T2)
    # noise-free projections meet x2^T F x1 = 0; the 0.2 px noise keeps them within a pixel
    line = np.c_[xy1, np.ones(len(xy1))] @ F.T
    dist = np.abs(np.sum(line * np.c_[xy2, np.ones(len(xy2))], 1)) / np.hypot(line[:, 0], line[:, 1])
    assert dist.max() < 1.0 and np.linalg.norm(F) == pytest.approx(1.0)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_matches_equal_the_brute_force_twin(seed):
    rng = np.random.default_rng(seed)
    (K1, T1, K2, T2), xy1, xy2, d1, d2 = _scene(rng)
    F = guided.fundamental(K1, T1, K2, T2)
    got = guided.epipolar_matches(xy1, xy2, d1, d2, F)
    want = _twin(xy1, xy2, d1, d2, F, guided.EPIPOLAR_PX, guided.RATIO, guided.MAX_ANGLE)
    np.testing.assert_array_equal(got, want)
    # and a wider band admits other candidates: the twin follows there as well
    got = guided.epipolar_matches(xy1, xy2, d1, d2, F, max_px=40.0)
    np.testing.assert_array_equal(got, _twin(xy1, xy2, d1, d2, F, 40.0, guided.RATIO, guided.MAX_ANGLE))


def test_repeated_structure_is_matched_only_along_the_epipolar_line():
    """A feature whose descriptor appears twice in the other image: the global ratio test drops
    it, the epipolar band keeps the copy on the line and never the one off it."""
    rng = np.random.default_rng(3)
    (K1, T1, K2, T2), xy1, xy2, d1, d2 = _scene(rng, n_clutter=0)
    n = len(xy1)
    F = guided.fundamental(K1, T1, K2, T2)
    # an exact copy of each of image 2's descriptors, 60 px off its epipolar line
    line = np.c_[xy1, np.ones(n)] @ F.T
    normal = line[:, :2] / np.hypot(line[:, 0], line[:, 1])[:, None]
    xy2r = np.r_[xy2, xy2 + 60.0 * normal]
    d2r = np.r_[d2, d2]
    got = guided.epipolar_matches(xy1, xy2r, d1, d2r, F)
    assert len(got) >= 0.9 * n
    np.testing.assert_array_equal(got[:, 1], got[:, 0])      # always the true one, never a copy
    # the same descriptors matched over the whole image: the copies defeat the ratio test
    everywhere = guided.epipolar_matches(xy1, xy2r, d1, d2r, F, max_px=1e6)
    assert len(everywhere) == 0


def test_no_candidates_and_empty_inputs():
    rng = np.random.default_rng(4)
    (K1, T1, K2, T2), xy1, xy2, d1, d2 = _scene(rng)
    F = guided.fundamental(K1, T1, K2, T2)
    assert guided.epipolar_matches(xy1[:0], xy2, d1[:0], d2, F).shape == (0, 2)
    # the noisy features lie on no line exactly
    assert guided.epipolar_matches(xy1, xy2, d1, d2, F, max_px=0.0).shape == (0, 2)


def test_a_match_must_be_mutual():
    """Rectified cameras (epipolar lines are the rows): a's only candidate is b, but b prefers
    a2, whose descriptor is b's own, so only (a2, b) is a match."""
    F = np.array([[0.0, 0, 0], [0, 0, -1], [0, 1, 0]])
    v = np.zeros(128)
    v[:8] = 100
    u = v.copy()
    u[8:11] = 30                                             # 0.18 rad from v
    xy1 = np.array([[100.0, 50], [200, 50], [300, 90]])      # a, a2, and c on another row
    xy2 = np.array([[150.0, 50.4], [320, 300]])              # b, and d on no row of image 1
    d1 = np.stack([u, v, v]).astype(np.uint8)
    d2 = np.stack([v, v]).astype(np.uint8)
    np.testing.assert_array_equal(guided.epipolar_matches(xy1, xy2, d1, d2, F), [[1, 0]])
    # without a2, a is b's only candidate as well: then (a, b) is the match
    np.testing.assert_array_equal(guided.epipolar_matches(xy1[[0, 2]], xy2, d1[[0, 2]], d2, F), [[0, 0]])
