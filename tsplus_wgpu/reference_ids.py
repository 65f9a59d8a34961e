"""Float64 NumPy twin of ``shaders/rasterize_ids.wgsl``: per pixel the triangle with the
largest blending weight alpha * T, walking the triangles front to back exactly as the
forward blend does (:func:`tsplus_wgpu.reference.blend`); ties go to the front-most
triangle, -1 where no triangle contributes.

Besides the IDs it returns the best and the second-best weight of every pixel, so a test
can leave out pixels where float32 arithmetic may legitimately pick the other triangle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .types import Camera, TriangleModel


@dataclass
class IdResult:
    ids: np.ndarray         # [H, W] int64, -1 where no triangle contributes
    weight: np.ndarray      # [H, W] the winner's alpha * T (0 where none)
    second: np.ndarray      # [H, W] the largest weight among the other triangles
    ambiguous: np.ndarray   # [H, W] a discrete decision was within rounding of flipping (as reference.blend)


def blend_ids(proj, order, width, height, ambiguity_tol=1e-4, sigma=None):
    """Twin of rasterize_ids on projected triangles ``proj`` (a :class:`reference.Projection`)
    drawn in ``order``. ``sigma`` is the window sharpness (required)."""
    from .reference import ALPHA_MAX, ALPHA_MIN, T_MIN
    if sigma is None:
        raise ValueError("sigma: required")
    h, w = height, width
    T = np.ones((h, w))
    done = np.zeros((h, w), bool)
    amb = np.zeros((h, w), bool)
    ids = np.full((h, w), -1, np.int64)
    best = np.zeros((h, w))
    second = np.zeros((h, w))
    tol = ambiguity_tol
    for t in order:
        if not proj.visible[t]:
            continue
        x0, y0, x1, y1 = proj.rect[t]
        sl = (slice(y0, y1 + 1), slice(x0, x1 + 1))
        ys, xs = np.mgrid[y0:y1 + 1, x0:x1 + 1]
        d = np.stack([xs + 0.5 - proj.s[t, 0], ys + 0.5 - proj.s[t, 1]], axis=-1)
        ratio = (1.0 + d @ proj.g[t].T).min(axis=-1)
        live = ~done[sl]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            win = np.where(ratio > 0, np.power(np.maximum(ratio, 1e-300), sigma), 0.0)
        alpha = np.minimum(ALPHA_MAX, proj.opacity[t] * win)
        valid = live & (ratio > 0) & (alpha >= ALPHA_MIN)
        Tloc = T[sl]
        nxt = Tloc * (1.0 - alpha)
        stop = valid & (nxt < T_MIN)
        add = valid & ~stop
        amb[sl] |= live & ((np.abs(ratio) < tol) | (np.abs(alpha - ALPHA_MIN) < tol * ALPHA_MIN)
                           | ((ratio > 0) & (alpha >= ALPHA_MIN) & (np.abs(nxt - T_MIN) < tol * T_MIN)))
        wgt = np.where(add, alpha * Tloc, 0.0)
        b, s2 = best[sl], second[sl]
        better = add & (wgt > b)
        second[sl] = np.where(better, b, np.maximum(s2, wgt))
        best[sl] = np.where(better, wgt, b)
        ids[sl] = np.where(better, t, ids[sl])
        T[sl] = np.where(add, nxt, Tloc)
        done[sl] |= stop
    return IdResult(ids=ids, weight=best, second=second, ambiguous=amb)


def triangle_ids(model: TriangleModel, camera: Camera, sigma, near=0.01, ambiguity_tol=1e-4):
    """Float64 triangle-ID buffer; same arguments and meaning as ``Renderer.forward(...,
    triangle_ids=True).triangle_ids`` (the model is drawn as it is: no opacity override)."""
    from . import reference
    sigma, _, near = reference._check_args(sigma, (0.0, 0.0, 0.0), near)
    if not isinstance(model, TriangleModel):
        raise ValueError("model: expected a TriangleModel")
    if not isinstance(camera, Camera):
        raise ValueError("camera: expected a Camera")
    proj = reference.project(model, camera, sigma, near)
    return blend_ids(proj, reference.depth_order(proj), camera.width, camera.height, ambiguity_tol, sigma=sigma)
