"""Float64 NumPy twins of ``shaders/blend/``: the forward blend (:func:`rasterize_forward`)
and its triangle-ID variant (:func:`rasterize_ids`: per pixel the triangle with the largest
blending weight alpha * T, walking the triangles front to back exactly as the forward blend
does; ties go to the front-most triangle, -1 where no triangle contributes), plus the whole
ID pass from a model (:func:`triangle_ids`), and the gather of a window's projected triangles
in pair order (:func:`gather_tris`).

Besides the IDs the ID twin returns the best and the second-best weight of every pixel, so a
test can leave out pixels where float32 arithmetic may legitimately pick the other triangle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..types import Camera, TriangleModel, check_render_args
from .project import ALPHA_MAX, ALPHA_MIN, T_MIN, Projection, projection
from .sort import depth_order


@dataclass
class RenderResult:
    image: np.ndarray          # [H, W, 3]
    transmittance: np.ndarray  # [H, W]
    max_weight: np.ndarray     # [M]
    n_contrib: np.ndarray      # [H, W] triangles that contributed
    ambiguous: np.ndarray      # [H, W] a discrete decision was within rounding of flipping
    f32_bound: np.ndarray      # [H, W] first-order float32 error estimate of the image
    projection: Projection


def rasterize_forward(proj: Projection, order, width, height, sigma, background=(0.0, 0.0, 0.0), ambiguity_tol=1e-4):
    """Twin of rasterize_forward: composite the projected triangles in ``order`` (front to back)."""
    bg = np.asarray(background, np.float64)
    h, w = height, width
    m = proj.s.shape[0]
    C = np.zeros((h, w, 3))
    T = np.ones((h, w))
    done = np.zeros((h, w), bool)
    amb = np.zeros((h, w), bool)
    count = np.zeros((h, w), np.int64)
    max_weight = np.zeros(m)
    # First-order float32 error model: a projected vertex is known to about one ulp of
    # its pixel coordinate (a few roundings: 2^-22 relative), which moves e_k by that much
    # times |g_k| (1 / inradius).
    pts = proj.verts2d if proj.verts2d is not None else proj.s[:, None, :]
    scale = np.abs(np.nan_to_num(pts, posinf=0.0, neginf=0.0)).reshape(m, -1).max(axis=1)
    de = 2.0 ** -22 * (1.0 + scale) * np.linalg.norm(proj.g, axis=2).max(axis=1)          # [M]
    if proj.vcolors is not None:
        cspread = np.ptp(proj.vcolors, axis=1).max(axis=1)
    else:  # colour plane only: spread over the triangle ~ |gradient| * size
        cspread = np.zeros(m)
    bound = np.zeros((h, w))
    for t in order:
        if not proj.visible[t]:
            continue
        x0, y0, x1, y1 = proj.rect[t]
        ys, xs = np.mgrid[y0:y1 + 1, x0:x1 + 1]
        d = np.stack([xs + 0.5 - proj.s[t, 0], ys + 0.5 - proj.s[t, 1]], axis=-1)   # [h', w', 2]
        e = 1.0 + d @ proj.g[t].T                                                   # [h', w', 3]
        ratio = e.min(axis=-1)
        live = ~done[y0:y1 + 1, x0:x1 + 1]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            pos = np.maximum(ratio, 1e-300)
            win = np.where(ratio > 0, np.power(pos, sigma), 0.0)
            slope = np.where(ratio > 0, proj.opacity[t] * sigma * np.power(pos, sigma - 1.0), 0.0)
        alpha = np.minimum(ALPHA_MAX, proj.opacity[t] * win)
        valid = live & (ratio > 0) & (alpha >= ALPHA_MIN)
        Tloc = T[y0:y1 + 1, x0:x1 + 1]
        nxt = Tloc * (1.0 - alpha)
        stop = valid & (nxt < T_MIN)
        contrib = valid & ~stop
        tol = ambiguity_tol
        amb[y0:y1 + 1, x0:x1 + 1] |= live & (
            (np.abs(ratio) < tol) | (np.abs(alpha - ALPHA_MIN) < tol * ALPHA_MIN)
            | ((ratio > 0) & (alpha >= ALPHA_MIN) & (np.abs(nxt - T_MIN) < tol * T_MIN)))
        sens = np.where(alpha < ALPHA_MAX, slope, 0.0) + alpha * cspread[t]
        bound[y0:y1 + 1, x0:x1 + 1] += np.where(valid, sens * de[t], 0.0)
        col = proj.color[t] + d[..., :1] * proj.dcolor_dx[t] + d[..., 1:] * proj.dcolor_dy[t]   # [h', w', 3]
        wgt = alpha * Tloc
        C[y0:y1 + 1, x0:x1 + 1] += np.where(contrib[..., None], col * wgt[..., None], 0.0)
        if contrib.any():
            max_weight[t] = max(max_weight[t], float(wgt[contrib].max()))
        T[y0:y1 + 1, x0:x1 + 1] = np.where(contrib, nxt, Tloc)
        count[y0:y1 + 1, x0:x1 + 1] += contrib
        done[y0:y1 + 1, x0:x1 + 1] |= stop
    image = C + T[..., None] * bg[None, None, :]
    return RenderResult(image=image, transmittance=T, max_weight=max_weight, n_contrib=count,
                        ambiguous=amb, f32_bound=bound, projection=proj)


@dataclass
class IdResult:
    ids: np.ndarray         # [H, W] int64, -1 where no triangle contributes
    weight: np.ndarray      # [H, W] the winner's alpha * T (0 where none)
    second: np.ndarray      # [H, W] the largest weight among the other triangles
    ambiguous: np.ndarray   # [H, W] a discrete decision was within rounding of flipping (as rasterize_forward)


#: the GPU layout's forward (``rasterize_forward_gpu.wgsl``) is the same model: the same twin
rasterize_forward_gpu = rasterize_forward


def rasterize_ids(proj, order, width, height, ambiguity_tol=1e-4, sigma=None):
    """Twin of the triangle-ID pass (rasterize_forward with ``TRIANGLE_IDS``) on projected
    triangles ``proj`` (a :class:`Projection`) drawn in ``order``. ``sigma`` is the window
    sharpness (required)."""
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
    sigma, _, near = check_render_args(sigma, (0.0, 0.0, 0.0), near)
    if not isinstance(model, TriangleModel):
        raise ValueError("model: expected a TriangleModel")
    if not isinstance(camera, Camera):
        raise ValueError("camera: expected a Camera")
    proj = projection(model, camera, sigma, near)
    return rasterize_ids(proj, depth_order(proj), camera.width, camera.height, ambiguity_tol, sigma=sigma)


def gather_tris(records, pair_tris, lo, count):
    """The projected triangles of pairs ``[lo, lo + count)`` in pair order: ``records[pair_tris[lo
    + p]]`` for p < count (``records``: ``[M]`` rows of any dtype, e.g. the ``Tri2D`` bytes).
    Copies, so exact."""
    ids = np.asarray(pair_tris, np.int64)[int(lo):int(lo) + int(count)]
    return np.asarray(records)[ids].copy()

