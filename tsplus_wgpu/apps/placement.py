"""Where an exported mesh stands in an engine: its origin on the ground, its size in metres.

A reconstruction's world has an arbitrary origin and unit as well as an arbitrary up: COLMAP's
are wherever its first photos put them. ``tsplus export --y-up`` turns the cameras' up to +Y
(:mod:`~tsplus_wgpu.data.upright`); :func:`find_placement` also finds

* **the middle of the scene** across the ground: where the cameras' viewing directions, laid
  flat, meet (the object of an orbit) when they face many ways; the cameras' own middle when
  they all face one way (a walk down a street); a smooth blend between the two;
* **the ground**: the height with the most level surface (normal within :data:`LEVEL_DEG` of
  up) below the cameras, near them across the ground (:data:`ACROSS`) and at most
  :data:`REACH` times their scale down, so that the background shell, five or more times it
  away, is never taken for it. A trained mesh is rough (on the shared scenes only 11 % of the
  area at the ground's height has a normal within 15 degrees of up), so the ground is found as a
  peak of height, not as a plane fitted to normals. Below :data:`MIN_SHARE` of the level area
  in the peak, nothing looks like ground (the fox, a head mounted on a wall: 15 %; the cup's
  table 51 %, lund's street 47 %, office's floor 31 %) and :class:`PlacementError` says so.
  A trained mesh does not reach under the cameras themselves (no photo sees straight down), so
  a ray down from each camera, as the viewer's walking mode casts, found ground below 3 of lund's
  29 cameras and none of office's.

The origin goes on the ground under the middle. The scale is a factor given by the user, or the
one that puts the cameras' median height a given height above the ground (photos taken standing:
about 1.5 m). :func:`engine_frame` makes the 4x4 similarity ``file = s A (p - o)`` the export
writes and records (:mod:`~tsplus_wgpu.io.export`), so ``tsplus eval`` and ``view`` read the
file back into the photos' world. Everything is float64 NumPy and deterministic.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: a surface is level ground when its normal is within this angle of up (either side: the
#: triangles' winding says nothing)
LEVEL_DEG = 45.0
#: how far below the cameras the ground may lie, in the cameras' scale (:func:`cameras_scale`): the
#: background shell, at five or more times it, is never taken for the ground
REACH = 2.0
#: how far from the middle across the ground it is looked for: this many times the farthest camera
ACROSS = 1.5
#: the least share of the level area near the cameras that the ground's height must hold
MIN_SHARE = 0.2
#: the cameras' flat viewing directions meet when the smaller spread of their lines is over
#: ``_SPREAD_HI`` (a share of the cameras: 0.5 for directions all round); under ``_SPREAD_LO``
#: they face one way and the cameras' middle is taken; a blend between
_SPREAD_LO, _SPREAD_HI = 0.05, 0.15


class PlacementError(ValueError):
    """No ground to stand the mesh on (one line, for the command)."""


@dataclass
class Placement:
    """``origin`` (world point that becomes the engine's origin), ``ground`` (the up-coordinate
    of the ground), ``camera_height`` (the cameras' median height above it, world units),
    ``cameras`` (how many), ``share`` (the ground's share of the level area looked at) and
    ``middle`` (which rule placed the origin across the ground)."""
    origin: np.ndarray
    ground: float
    camera_height: float
    cameras: int
    share: float
    middle: str


def _unit(v):
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


def cameras_scale(centers, middle) -> float:
    """The cameras' scale: the larger of their spread (rms distance from their mean) and their
    median distance from ``middle``; 1 for a single camera on the middle."""
    c = np.asarray(centers, np.float64)
    spread = float(np.sqrt(np.mean(np.sum((c - c.mean(0)) ** 2, axis=1))))
    dist = float(np.median(np.linalg.norm(c - middle, axis=1)))
    s = max(spread, dist)
    return s if s > 0 else 1.0


def flat_middle(centers, directions, up) -> tuple:
    """``(point, words)``: the middle of the scene across the ground (its up-coordinate is the
    cameras' mean height): where the cameras' flat viewing lines meet, blended with the cameras'
    mean as the lines close into one direction (see the module header)."""
    c = np.asarray(centers, np.float64)
    up = _unit(up)
    mean = c.mean(0)
    d = np.asarray(directions, np.float64)
    d = d - np.outer(d @ up, up)
    n = np.linalg.norm(d, axis=1)
    keep = n > 0.2                                     # cameras looking nearly straight down say nothing
    if keep.sum() < 2:
        return mean, "the cameras' middle (they look straight down)"
    d = d[keep] / n[keep, None]
    plane = np.eye(3) - np.outer(up, up)
    m = len(d) * plane - d.T @ d                      # sum of the projectors across each flat line
    b = plane @ c[keep].sum(0) - d.T @ np.einsum("ij,ij->i", d, c[keep])
    ev, vec = np.linalg.eigh(m)
    inplane = [i for i in range(3) if abs(vec[:, i] @ up) < 0.5]
    spread = float(min(ev[i] for i in inplane)) / len(d)
    w = float(np.clip((spread - _SPREAD_LO) / (_SPREAD_HI - _SPREAD_LO), 0.0, 1.0))
    if w > 0:
        meet = np.linalg.lstsq(m + np.outer(up, up), b + up * (up @ mean), rcond=None)[0]
        if np.median(np.einsum("ij,ij->i", meet - c[keep], d)) <= 0:     # behind the cameras: no meeting
            w = 0.0
    point = mean if w == 0 else w * meet + (1 - w) * mean
    point = point - up * (point @ up) + up * (mean @ up)
    words = ("where the cameras' viewing directions meet" if w >= 1 else
             "the cameras' middle (they face one way)" if w <= 0 else
             "between where the cameras' viewing directions meet and the cameras' middle")
    return point, words


def level_ground(positions, triangles, up, middle, reach_across, top, reach_down):
    """``(height, share)``: the up-coordinate of the ground and the share of the level area near it,
    or ``(None, 0)``. The ground is the height with the most level surface (triangles whose
    normal is within :data:`LEVEL_DEG` of up, either side) within ``reach_across`` of ``middle``
    across the ground and between ``top - reach_down`` and ``top``; each triangle counts its
    area, capped at the 95th percentile of theirs so that a few large shards cannot outvote a
    surface the photos saw in detail. Heights are binned at 1 % of ``reach_down``, the bins
    smoothed over three; the height is the area-weighted median within two bins of the peak."""
    v = np.asarray(positions, np.float64)
    t = np.asarray(triangles, np.int64).reshape(-1, 3)
    if len(t) == 0:
        return None, 0.0
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    n = np.cross(b - a, c - a)
    area2 = np.linalg.norm(n, axis=1)
    cen = (a + b + c) / 3.0
    h = cen @ up
    across = np.linalg.norm((cen - middle) - np.outer((cen - middle) @ up, up), axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        level = np.abs(n @ up) >= np.cos(np.radians(LEVEL_DEG)) * area2
    keep = level & (area2 > 0) & (across <= reach_across) & (h < top) & (h >= top - reach_down)
    if not keep.any():
        return None, 0.0
    h, w = h[keep], 0.5 * area2[keep]
    w = np.minimum(w, np.percentile(w, 95))
    width = 0.01 * reach_down
    bins = np.floor((h - (top - reach_down)) / width).astype(np.int64)
    hist = np.bincount(bins, weights=w, minlength=101)
    smooth = np.convolve(hist, np.ones(3), mode="same")
    peak = int(np.argmax(smooth))
    near = np.abs(bins - peak) <= 2
    order = np.argsort(h[near], kind="stable")
    cum = np.cumsum(w[near][order])
    height = float(h[near][order][np.searchsorted(cum, 0.5 * cum[-1])])
    return height, float(w[near].sum() / w.sum())


def find_placement(positions, triangles, centers, directions, up) -> Placement:
    """Where the mesh ``positions`` / ``triangles`` stands: see the module header. ``centers`` and
    ``directions`` are the cameras' centres and viewing directions in the world, ``up`` the
    scene's up. Raises :class:`PlacementError` when no level surface lies below the cameras."""
    c = np.asarray(centers, np.float64).reshape(-1, 3)
    if len(c) == 0:
        raise PlacementError("no cameras to find the ground from")
    up = _unit(up)
    middle, words = flat_middle(c, directions, up)
    scale = cameras_scale(c, middle)
    flat = (c - middle) - np.outer((c - middle) @ up, up)
    across = ACROSS * max(float(np.max(np.linalg.norm(flat, axis=1))), scale)
    top = float(np.median(c @ up))
    ground, share = level_ground(positions, triangles, up, middle, across, top, REACH * scale)
    if ground is None:
        raise PlacementError("no level surface below the cameras")
    if share < MIN_SHARE:
        raise PlacementError(f"nothing below the cameras looks like ground (the most level surface at one height "
                             f"holds {share:.0%} of the level area near them, under {MIN_SHARE:.0%})")
    height = float(np.median(c @ up - ground))
    origin = middle - up * (middle @ up) + up * ground
    return Placement(origin, ground, height, len(c), share, words)


def engine_frame(rotation, origin=None, scale=1.0) -> np.ndarray:
    """The 4x4 similarity ``file = scale * rotation @ (p - origin)`` (``origin`` None: the world's)."""
    m = np.eye(4)
    a = float(scale) * np.asarray(rotation, np.float64)
    m[:3, :3] = a
    if origin is not None:
        m[:3, 3] = -a @ np.asarray(origin, np.float64)
    return m
