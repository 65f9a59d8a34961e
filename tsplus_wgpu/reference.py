"""Float64 NumPy twin of the forward rasterizer: the same model and conventions as the
WGSL kernels, written for clarity. Tests compare every kernel against it.

The model (method.md):
  * vertex colour ``c_v = max(0, SH(dir_v) + 0.5)``, dir_v the unit vector from the
    camera centre to the vertex (zero at the centre itself: DC only);
  * a triangle with any vertex at camera z <= near is not drawn; nor one whose
    opacity o_T = min of its vertices' is below 1/255 (it could never reach alpha 1/255),
    nor one numerically degenerate on screen (2*area / perimeter^2 < 1e-6);
  * window ``I(p) = max(0, phi(p)/phi(s))^sigma`` with ``phi(p)/phi(s) = min_k e_k(p)``,
    ``e_k(p) = 1 + g_k . (p - s)``, s the incenter, g_k = -n_k / r;
  * colour at p: screen-space barycentric interpolation, b_k = e_k(p) len_k / perimeter;
  * ``alpha = min(0.99, o_T I)``; skip alpha < 1/255; front to back by centroid camera z
    (ties in triangle order); stop before T would fall below 1e-4; out = C + T * bg.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .types import Camera, TriangleModel

TILE = 16
ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
T_MIN = 1e-4
MIN_THINNESS = 1e-6
BIN_MARGIN = 1e-5

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
         -0.4570457994644658, 1.445305721320277, -0.5900435899266435)


def sh_basis(dirs, k):
    """Real SH basis [N, k] at unit directions [N, 3] (degree <= 3, 3DGS sign convention)."""
    x, y, z = dirs[:, 0], dirs[:, 1], dirs[:, 2]
    cols = [np.full_like(x, SH_C0)]
    if k > 1:
        cols += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if k > 4:
        xx, yy, zz = x * x, y * y, z * z
        cols += [SH_C2[0] * x * y, SH_C2[1] * y * z, SH_C2[2] * (2 * zz - xx - yy),
                 SH_C2[3] * x * z, SH_C2[4] * (xx - yy)]
    if k > 9:
        cols += [SH_C3[0] * y * (3 * xx - yy), SH_C3[1] * x * y * z, SH_C3[2] * y * (4 * zz - xx - yy),
                 SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy), SH_C3[4] * x * (4 * zz - xx - yy),
                 SH_C3[5] * z * (xx - yy), SH_C3[6] * x * (xx - 3 * yy)]
    return np.stack(cols[:k], axis=1)


def vertex_colors(positions, sh, cam_center):
    """[N, 3] colours max(0, SH(dir) + 0.5)."""
    delta = positions - cam_center[None, :]
    length = np.linalg.norm(delta, axis=1, keepdims=True)
    dirs = np.where(length > 0, delta / np.where(length > 0, length, 1.0), 0.0)
    basis = sh_basis(dirs, sh.shape[1])                     # [N, K]
    return np.maximum(np.einsum("nk,nkc->nc", basis, sh) + 0.5, 0.0)


@dataclass
class Projection:
    """Per-triangle projected data (float64). ``visible`` False means not drawn."""
    visible: np.ndarray     # [M] bool
    verts2d: np.ndarray     # [M, 3, 2]
    s: np.ndarray           # [M, 2] incenter
    g: np.ndarray           # [M, 3, 2] edge gradients, e_k(p) = 1 + g_k . (p - s)
    lengths: np.ndarray     # [M, 3] side k opposite vertex k
    inradius: np.ndarray    # [M]
    opacity: np.ndarray     # [M]
    tau: np.ndarray         # [M] window ratio where alpha = 1/255
    depth: np.ndarray       # [M] centroid camera z
    vcolors: np.ndarray     # [M, 3, 3] vertex colours
    rect: np.ndarray        # [M, 4] inclusive pixel box (x0, y0, x1, y1) of the alpha >= 1/255 region
    color: np.ndarray       # [M, 3] colour at s; c(p) = color + dcolor_dx (p-s).x + dcolor_dy (p-s).y
    dcolor_dx: np.ndarray   # [M, 3]
    dcolor_dy: np.ndarray   # [M, 3]


def project(model: TriangleModel, camera: Camera, sigma, near=0.01):
    R, t = camera.R, camera.t
    colors = vertex_colors(model.positions, model.sh, camera.center)
    xc = model.positions @ R.T + t                                 # [N, 3]
    tri = model.triangles
    m = tri.shape[0]
    z = xc[tri, 2]                                                  # [M, 3]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        uv = np.stack([camera.fx * xc[:, 0] / xc[:, 2] + camera.cx,
                       camera.fy * xc[:, 1] / xc[:, 2] + camera.cy], axis=1)
        p = uv[tri]                                                 # [M, 3, 2]
        visible = np.all(z > near, axis=1)
        opacity = model.opacity[tri].min(axis=1)
        visible &= opacity >= ALPHA_MIN
        lengths = np.stack([np.linalg.norm(p[:, 1] - p[:, 2], axis=1),
                            np.linalg.norm(p[:, 2] - p[:, 0], axis=1),
                            np.linalg.norm(p[:, 0] - p[:, 1], axis=1)], axis=1)
        perim = lengths.sum(axis=1)
        e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
        area2 = np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
        visible &= (perim > 0) & (area2 >= MIN_THINNESS * perim * perim) & (area2 < 3e38)
        perim_safe = np.where(visible, perim, 1.0)
        r = np.where(visible, area2 / perim_safe, 1.0)
        s = p[:, 0] + (lengths[:, 1:2] * e1 + lengths[:, 2:3] * e2) / perim_safe[:, None]
        g = np.zeros((m, 3, 2))
        for k in range(3):
            a, b = p[:, (k + 1) % 3], p[:, (k + 2) % 3]
            d = (b - a) / np.where(visible, lengths[:, k], 1.0)[:, None]
            n = np.stack([d[:, 1], -d[:, 0]], axis=1)
            flip = np.einsum("mi,mi->m", n, p[:, k] - a) > 0
            n[flip] *= -1
            g[:, k] = -n / r[:, None]
        tau = np.exp2(np.log2(ALPHA_MIN / np.maximum(opacity, 1e-300)) / sigma)
        shrink = 1.0 - (tau - BIN_MARGIN)
        q = s[:, None, :] + shrink[:, None, None] * (p - s[:, None, :])
        lo, hi = q.min(axis=1), q.max(axis=1)
        lim = np.array([camera.width, camera.height], dtype=np.float64)
        plo = np.clip(np.ceil(lo - 0.5), -1, lim)
        phi = np.clip(np.floor(hi - 0.5), -1, lim)
    plo = np.nan_to_num(plo, nan=1.0)
    phi = np.nan_to_num(phi, nan=0.0)
    rect = np.stack([np.maximum(plo[:, 0], 0), np.maximum(plo[:, 1], 0),
                     np.minimum(phi[:, 0], camera.width - 1), np.minimum(phi[:, 1], camera.height - 1)],
                    axis=1).astype(np.int64)
    visible &= (rect[:, 0] <= rect[:, 2]) & (rect[:, 1] <= rect[:, 3])
    rect[~visible] = (1, 1, 0, 0)
    vcol = colors[tri]                                              # [M, 3, 3]
    wts = lengths / perim_safe[:, None]                             # barycentrics at s
    color = np.einsum("mk,mkc->mc", wts, vcol)
    dcdx = np.einsum("mk,mk,mkc->mc", wts, g[:, :, 0], vcol)
    dcdy = np.einsum("mk,mk,mkc->mc", wts, g[:, :, 1], vcol)
    return Projection(visible=visible, verts2d=p, s=s, g=g, lengths=lengths, inradius=r, opacity=opacity,
                      tau=tau, depth=z.mean(axis=1), vcolors=vcol, rect=rect, color=color, dcolor_dx=dcdx,
                      dcolor_dy=dcdy)


def depth_order(proj: Projection):
    """Drawing order: visible triangles by centroid depth, ties in index order."""
    key = np.where(proj.visible, proj.depth, np.inf)
    return np.argsort(key, kind="stable")


def tile_overlaps(s, g, tau, rect, tx, ty):
    """Vectorised twin of shaders/common/triangle.wgsl:tile_overlaps for one triangle
    over arrays of tile coordinates."""
    x0 = np.maximum(rect[0], tx * TILE)
    y0 = np.maximum(rect[1], ty * TILE)
    x1 = np.minimum(rect[2], tx * TILE + TILE - 1)
    y1 = np.minimum(rect[3], ty * TILE + TILE - 1)
    ok = (x0 <= x1) & (y0 <= y1)
    lo = np.stack([x0, y0], -1) + 0.5
    hi = np.stack([x1, y1], -1) + 0.5
    thr = tau - BIN_MARGIN
    for k in range(3):
        corner = np.where(g[k][None, :] > 0, hi, lo)
        e = 1.0 + (corner - s[None, :]) @ g[k]
        ok &= e >= thr
    return ok


def bin_pairs(s, g, tau, rect, order, width, height):
    """Twin of bin_count/bin_emit + the stable sort by tile: (pair_tiles, pair_tris)
    ordered by tile, then depth rank. Inputs are per-triangle arrays (any float type)."""
    tiles_x = (width + TILE - 1) // TILE
    all_tiles, all_tris = [], []
    for t in order:
        r = rect[t]
        if r[0] > r[2] or r[1] > r[3]:
            continue
        ty, tx = np.meshgrid(np.arange(r[1] // TILE, r[3] // TILE + 1), np.arange(r[0] // TILE, r[2] // TILE + 1),
                             indexing="ij")
        tx, ty = tx.ravel(), ty.ravel()
        ok = tile_overlaps(np.asarray(s[t], np.float64), np.asarray(g[t], np.float64), float(tau[t]), r, tx, ty)
        all_tiles.append((ty[ok] * tiles_x + tx[ok]).astype(np.int64))
        all_tris.append(np.full(int(ok.sum()), t, np.int64))
    if not all_tiles:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    tiles = np.concatenate(all_tiles)
    tris = np.concatenate(all_tris)
    idx = np.argsort(tiles, kind="stable")
    return tiles[idx], tris[idx]


@dataclass
class RenderResult:
    image: np.ndarray          # [H, W, 3]
    transmittance: np.ndarray  # [H, W]
    max_weight: np.ndarray     # [M]
    n_contrib: np.ndarray      # [H, W] triangles that contributed
    ambiguous: np.ndarray      # [H, W] a discrete decision was within rounding of flipping
    f32_bound: np.ndarray      # [H, W] first-order float32 error estimate of the image
    projection: Projection


def _check_args(sigma, background, near):
    try:
        sigma = float(sigma)
    except Exception:
        raise ValueError(f"sigma: expected a number, got {sigma!r}") from None
    if not np.isfinite(sigma) or sigma <= 0:
        raise ValueError(f"sigma: must be finite and > 0, got {sigma!r}")
    bg = np.asarray(background, dtype=np.float64).ravel()
    if bg.shape != (3,) or not np.all(np.isfinite(bg)):
        raise ValueError(f"background: expected 3 finite numbers, got {background!r}")
    try:
        near = float(near)
    except Exception:
        raise ValueError(f"near: expected a number, got {near!r}") from None
    if not np.isfinite(near) or near < 0:
        raise ValueError(f"near: must be finite and >= 0, got {near!r}")
    return sigma, bg, near


def render(model: TriangleModel, camera: Camera, sigma, background=(0.0, 0.0, 0.0), near=0.01,
           ambiguity_tol=1e-4):
    """Float64 forward render; same arguments and outputs as ``Renderer.forward``.

    Besides ``image``, ``transmittance`` and ``max_weight`` the result carries
    ``ambiguous``: pixels where a discrete decision (inside/outside an edge, the 1/255
    skip, the T < 1e-4 stop) was within ``ambiguity_tol`` (relative) of flipping, where
    float32 arithmetic may legitimately decide the other way; and ``f32_bound``, a
    first-order estimate of the image error that float32 rounding of the projected
    vertices causes (large only where the window is steep: sigma < 1 near an edge, or
    thin triangles).
    """
    sigma, bg, near = _check_args(sigma, background, near)
    if not isinstance(model, TriangleModel):
        raise ValueError("model: expected a TriangleModel")
    if not isinstance(camera, Camera):
        raise ValueError("camera: expected a Camera")
    proj = project(model, camera, sigma, near)
    return blend(proj, depth_order(proj), camera.width, camera.height, sigma, bg, ambiguity_tol)


def blend(proj: Projection, order, width, height, sigma, background=(0.0, 0.0, 0.0), ambiguity_tol=1e-4):
    """Twin of rasterize_forward: composite the projected triangles in ``order``."""
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


def projection_from_records(records, rects):
    """A :class:`Projection` from the kernel's Tri2D records (structured array [M]) and
    pixel boxes [M, 4], so the blend twin can run on exactly the kernel's inputs."""
    rects = np.asarray(rects, np.int64)
    visible = (rects[:, 0] <= rects[:, 2]) & (rects[:, 1] <= rects[:, 3])
    f = lambda name: np.asarray(records[name], np.float64)
    g = np.stack([f("g0"), f("g1"), f("g2")], axis=1)
    return Projection(visible=visible, verts2d=None, s=f("s"), g=g, lengths=None, inradius=f("inradius"),
                      opacity=f("opacity"), tau=f("tau"), depth=f("depth"), vcolors=None, rect=rects,
                      color=f("color")[:, :3], dcolor_dx=f("dcolor_dx")[:, :3], dcolor_dy=f("dcolor_dy")[:, :3])
from .reference_backward import backward  # noqa: E402,F401  (float64 analytic backward)
from .reference_ids import triangle_ids  # noqa: E402,F401  (float64 twin of the triangle-ID pass)
