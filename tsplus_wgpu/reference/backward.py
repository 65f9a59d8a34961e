"""Float64 twins of ``shaders/backward/``, one per kernel, on the kernels' own inputs and
outputs (NumPy arrays in the buffers' layouts):

* :func:`backward_prepare` (per pixel): the backward blend's start state;
* :func:`rasterize_backward` (per tile): the replay of the blend and the 19 sufficient
  statistics per (triangle, tile) pair of ``shaders/common/grad_stats.wgsl``;
* :func:`project_backward` (per triangle): the chain rule from the statistics to the corners;
* :func:`vertex_backward` (per vertex): the SH chain rule from the summed corner gradients.

Tri2D records are ``[M, 24]`` floats: s (2), opacity, tau, g0, g1, g2 (2 each), depth,
inradius, colour (4), d colour / dx (4), d colour / dy (4) (``shaders/common/triangle.wgsl``).
"""

from __future__ import annotations

import numpy as np

from ..gpu.wgsl import constant
from ..sh import SH_C1, SH_C2, SH_C3, sh_basis
from ..types import Camera

NSTAT = constant("NSTAT", "grad_stats")
TILE = constant("TILE")
ALPHA_MIN = constant("ALPHA_MIN")
ALPHA_MAX = constant("ALPHA_MAX")


def backward_prepare(image, final_t, n_contrib, v_out):
    """Per pixel ``(T, acc, Z)`` = ``(1, 0, image . v_rgb + T_final * v_T)`` and the pixel's
    last contributing pair + 1 (``n_contrib[..., 0]``).

    Args: ``image [H, W, 3]``, ``final_t [H, W]``, ``n_contrib [H, W, 2]`` u32, ``v_out [H * W, 4]``.
    Returns: ``(state [H * W, 3]`` float64, ``last [H * W]`` u32).
    """
    v = np.asarray(v_out, np.float64).reshape(-1, 4)
    img = np.asarray(image, np.float64).reshape(-1, 3)
    z = np.einsum("pc,pc->p", img, v[:, :3]) + np.asarray(final_t, np.float64).reshape(-1) * v[:, 3]
    state = np.stack([np.ones_like(z), np.zeros_like(z), z], axis=1)
    return state, np.asarray(n_contrib, np.uint32).reshape(-1, 2)[:, 0].copy()


def _replay_pair(rec, px, py, live, st, v, sigma):
    """One pair at the tile's pixels ``live``: updates ``st`` (T, acc, Z columns) in place and
    returns (its 19 statistics, powered count, contributions)."""
    s, opacity, tau = rec[0:2], rec[2], rec[3]
    g = rec[4:10].reshape(3, 2)
    dx, dy = px - s[0], py - s[1]
    e = 1.0 + g[None, :, 0] * dx[:, None] + g[None, :, 1] * dy[:, None]      # [P, 3]
    ratio = e.min(axis=1)
    live = live & (ratio > 0) & (ratio >= tau)
    pr = np.maximum(ratio, 1e-30)
    win = pr ** sigma
    oi = opacity * win
    alpha = np.minimum(ALPHA_MAX, oi)
    valid = live & (alpha >= ALPHA_MIN)
    T = st[:, 0]
    col = rec[12:15][None, :] + rec[16:19][None, :] * dx[:, None] + rec[20:23][None, :] * dy[:, None]
    cv = np.einsum("pc,pc->p", col, v[:, :3])
    w = np.where(valid, alpha * T, 0.0)
    acc = st[:, 1] + cv * w
    with np.errstate(divide="ignore", invalid="ignore"):
        v_alpha = T * cv - (st[:, 2] - acc) / (1.0 - alpha)
        unclamped = valid & (oi < ALPHA_MAX)
        vo = np.where(unclamped, v_alpha * win, 0.0)
        vrat = np.where(unclamped, v_alpha * opacity * sigma * win / pr, 0.0)
    k0 = (e[:, 0] <= e[:, 1]) & (e[:, 0] <= e[:, 2])
    k1 = ~k0 & (e[:, 1] <= e[:, 2])
    kmin = np.where(k0, 0, np.where(k1, 1, 2))
    stats = np.zeros(NSTAT)
    moments = (np.ones_like(dx), dx, dy)
    for c in range(3):
        for m in range(3):
            stats[3 * c + m] = np.sum(w * v[:, c] * moments[m])
    for k in range(3):
        r = np.where(kmin == k, vrat, 0.0)
        for m in range(3):
            stats[9 + 3 * k + m] = np.sum(r * moments[m])
    stats[18] = np.sum(vo)
    st[:, 1] = acc
    st[:, 0] = np.where(valid, T * (1.0 - alpha), T)
    return stats, int(live.sum()), int(valid.sum())


def rasterize_backward(tris, ranges, pair_tris, v_out, state, last, width, height, tiles_x, sigma):
    """The backward blend: per tile, its pairs front to back, each pixel up to its last
    contributing pair, as ``rasterize_backward.wgsl`` (whatever its split into passes).

    Args:
        tris: ``[M, 24]`` Tri2D records; ranges: ``[tiles, 2]`` each tile's pairs
            ``[begin, end)``; pair_tris: ``[P]`` triangle of each sorted pair.
        v_out: ``[H * W, 4]`` dL/d rgb, dL/d T; state, last: :func:`backward_prepare`'s output.
        width, height, tiles_x, sigma: the frame's.

    Returns:
        ``(partials [P, NSTAT]`` (zero for pairs no pixel took), ``state [H * W, 3]`` (T, acc, Z
        after the replay), ``work [3]`` (pixel-pair evaluations, those reaching the window's
        power, contributions)).
    """
    tris = np.asarray(tris, np.float64).reshape(-1, 24)
    ranges = np.asarray(ranges, np.int64).reshape(-1, 2)
    v_out = np.asarray(v_out, np.float64).reshape(-1, 4)
    st_all = np.array(state, np.float64).reshape(-1, 3)
    last = np.asarray(last, np.int64).reshape(-1)
    partials = np.zeros((len(pair_tris), NSTAT))
    work = np.zeros(3, np.int64)
    for tile, (begin, end) in enumerate(ranges):
        ty, tx = divmod(tile, tiles_x)
        ys, xs = np.mgrid[ty * TILE:(ty + 1) * TILE, tx * TILE:(tx + 1) * TILE]
        inside = (xs < width) & (ys < height)
        pix = (ys * width + xs)[inside]
        px, py = xs[inside] + 0.5, ys[inside] + 0.5
        st, lst, v = st_all[pix], last[pix], v_out[pix]
        work[0] += lst.sum()
        for j in range(int(lst.max(initial=0))):
            stats, powered, added = _replay_pair(tris[pair_tris[begin + j]], px, py, j < lst, st, v, sigma)
            partials[begin + j] = stats
            work[1] += powered
            work[2] += added
        st_all[pix] = st
    return partials, st_all, work


def _cross(a, b):
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def min_vertex(opacity, triangles):
    """[M] the corner (0..2) whose vertex holds the triangle's minimum opacity; ties go
    to the tied vertex with the lowest global index."""
    op = opacity[triangles]                                                   # [M, 3]
    mn = op.min(axis=1, keepdims=True)
    ids = np.where(op == mn, triangles, np.iinfo(np.int64).max)
    return np.argmin(ids, axis=1)


def _corner_grads(S, A, col):
    """One triangle's chain rule: ([3, 3] dL/d corner colour, [3, 2] dL/d 2D corner)."""
    lens = np.array([np.linalg.norm(A[(k + 1) % 3] - A[(k + 2) % 3]) for k in range(3)])
    perim = lens.sum()
    E1, E2 = A[1] - A[0], A[2] - A[0]
    D = _cross(E1, E2)
    Vc = S[0:9].reshape(3, 3).T              # rows: the 1, d.x, d.y moments of (r, g, b)
    out_c = np.zeros((3, 3))
    gA = np.zeros((3, 2))
    F, y_over_l, vl = 0.0, 0.0, np.zeros(3)
    for k in range(3):
        i, j = (k + 1) % 3, (k + 2) % 3
        U, V = A[i], A[j]
        n = np.array([_cross(U, V), U[1] - V[1], V[0] - U[0]])
        out_c[k] = n @ Vc / D
        M = Vc @ col[k] + (perim / lens[k]) * S[9 + 3 * k:12 + 3 * k]
        F += M @ n
        Y = S[9 + 3 * k:12 + 3 * k] @ n / D
        gA[i] += (M[0] * np.array([V[1], -V[0]]) + np.array([-M[2], M[1]])) / D
        gA[j] += (M[0] * np.array([-U[1], U[0]]) + np.array([M[2], -M[1]])) / D
        y_over_l += Y / lens[k]
        vl[k] -= Y * perim / lens[k] ** 2
    vl += y_over_l                           # the perimeter depends on every side
    for k in range(3):
        i, j = (k + 1) % 3, (k + 2) % 3
        u = (A[i] - A[j]) / lens[k]
        gA[i] += vl[k] * u
        gA[j] -= vl[k] * u
    fd = F / (D * D)
    dD1, dD2 = np.array([E2[1], -E2[0]]), np.array([-E1[1], E1[0]])
    gA[1] -= fd * dD1
    gA[2] -= fd * dD2
    gA[0] += fd * (dD1 + dD2)
    return out_c, gA


def project_backward(positions, triangles, opacities, colors, tris, pixel_rects, tri_stats, camera: Camera):
    """Per triangle, its statistics to its three corners, as ``project_backward.wgsl``.

    Args:
        positions ``[N, 3]``, triangles ``[M, 3]``, opacities ``[N]``, colors ``[N, 4]`` (the
        forward's vertex colours), tris ``[M, 24]`` (Tri2D: the incenter s is the origin of the
        moments), pixel_rects ``[M, 4]`` (empty: no gradient), tri_stats ``[M, NSTAT]``.

    Returns:
        corner_grads ``[3 M, 2, 4]``: per corner (dL/d colour, dL/d opacity), (dL/d position, 0).
    """
    positions = np.asarray(positions, np.float64)
    triangles = np.asarray(triangles, np.int64).reshape(-1, 3)
    opacities = np.asarray(opacities, np.float64)
    colors = np.asarray(colors, np.float64).reshape(-1, 4)
    tris = np.asarray(tris, np.float64).reshape(-1, 24)
    stats = np.asarray(tri_stats, np.float64).reshape(-1, NSTAT)
    rects = np.asarray(pixel_rects).reshape(-1, 4)
    m = triangles.shape[0]
    out = np.zeros((m, 3, 2, 4))
    best = min_vertex(opacities, triangles) if m else np.zeros(0, np.int64)
    R = camera.R
    f = np.array([camera.fx, camera.fy])
    for t in range(m):
        if not (rects[t, 0] <= rects[t, 2] and rects[t, 1] <= rects[t, 3]):
            continue
        xc = positions[triangles[t]] @ R.T + camera.t                         # [3, 3] camera space
        A = f * xc[:, :2] / xc[:, 2:] + np.array([camera.cx, camera.cy]) - tris[t, 0:2]
        out_c, gA = _corner_grads(stats[t], A, colors[triangles[t], :3])
        vcam = np.concatenate([gA * f / xc[:, 2:],
                               -(gA[:, :1] * f[0] * xc[:, :1] + gA[:, 1:] * f[1] * xc[:, 1:2]) / xc[:, 2:] ** 2], 1)
        out[t, :, 0, :3] = out_c
        out[t, best[t], 0, 3] = stats[t, 18]
        out[t, :, 1, :3] = vcam @ R
    return out.reshape(3 * m, 2, 4)


def sh_basis_grad(dirs, k):
    """d basis / d dir: [N, k, 3] (the basis as a polynomial in x, y, z)."""
    x, y, z = dirs[:, 0], dirs[:, 1], dirs[:, 2]
    zero = np.zeros_like(x)
    C1, C2, C3 = SH_C1, SH_C2, SH_C3
    rows = [(zero, zero, zero)]
    if k > 1:
        rows += [(zero, -C1 + zero, zero), (zero, zero, C1 + zero), (-C1 + zero, zero, zero)]
    if k > 4:
        xx, yy, zz = x * x, y * y, z * z
        rows += [(C2[0] * y, C2[0] * x, zero), (zero, C2[1] * z, C2[1] * y),
                 (-2 * C2[2] * x, -2 * C2[2] * y, 4 * C2[2] * z), (C2[3] * z, zero, C2[3] * x),
                 (2 * C2[4] * x, -2 * C2[4] * y, zero)]
    if k > 9:
        rows += [(6 * C3[0] * x * y, C3[0] * (3 * xx - 3 * yy), zero),
                 (C3[1] * y * z, C3[1] * x * z, C3[1] * x * y),
                 (-2 * C3[2] * x * y, C3[2] * (4 * zz - xx - 3 * yy), 8 * C3[2] * y * z),
                 (-6 * C3[3] * x * z, -6 * C3[3] * y * z, C3[3] * (6 * zz - 3 * xx - 3 * yy)),
                 (C3[4] * (4 * zz - 3 * xx - yy), -2 * C3[4] * x * y, 8 * C3[4] * x * z),
                 (2 * C3[5] * x * z, -2 * C3[5] * y * z, C3[5] * (xx - yy)),
                 (C3[6] * (3 * xx - 3 * yy), -6 * C3[6] * x * y, zero)]
    return np.stack([np.stack(r, axis=1) for r in rows[:k]], axis=1)


def vertex_backward(positions, sh, vertex_sums, cam_center):
    """Per vertex, the SH chain rule, as ``vertex_backward.wgsl``: colour = max(0, SH(dir) . sh
    + 0.5), dir = (x - centre) / |x - centre|.

    Args:
        positions ``[N, 3]``, sh ``[N, K, 3]``, vertex_sums ``[N, 2, 4]`` (dL/d colour, dL/d
        opacity; dL/d position, -), cam_center ``[3]``.

    Returns:
        ``(v_positions [N, 3], v_sh [N, K, 3], v_opacity [N])``.
    """
    positions = np.asarray(positions, np.float64)
    sh = np.asarray(sh, np.float64)
    sums = np.asarray(vertex_sums, np.float64).reshape(-1, 2, 4)
    k = sh.shape[1]
    delta = positions - np.asarray(cam_center, np.float64)[None, :]
    length = np.linalg.norm(delta, axis=1)
    ok = length > 0
    safe = np.where(ok, length, 1.0)[:, None]
    dirs = np.where(ok[:, None], delta / safe, 0.0)
    basis = sh_basis(dirs, k)                                                 # [N, K]
    raw = np.einsum("nk,nkc->nc", basis, sh) + 0.5
    v_raw = np.where(raw > 0, sums[:, 0, :3], 0.0)
    v_sh = basis[:, :, None] * v_raw[:, None, :]
    v_dir = np.einsum("nki,nkc,nc->ni", sh_basis_grad(dirs, k), sh, v_raw)
    v_delta = (v_dir - dirs * np.einsum("ni,ni->n", dirs, v_dir)[:, None]) / safe
    v_pos = sums[:, 1, :3] + np.where(ok[:, None], v_delta, 0.0)
    return v_pos, v_sh, sums[:, 0, 3].copy()


#: the GPU layout's backward blend (``rasterize_backward_gpu.wgsl``) is the same model: the same twin
rasterize_backward_gpu = rasterize_backward


__all__ = ["NSTAT", "backward_prepare", "rasterize_backward", "rasterize_backward_gpu", "project_backward", "vertex_backward",
           "min_vertex", "sh_basis_grad"]
