"""Float64 twin of ``shaders/mesh/mesh_raster.wgsl`` drawn by the standard depth-tested render
pipeline of :class:`~tsplus_wgpu.render.mesh_renderer.MeshRenderer`: a z-buffer evaluated on
pixel centres."""

from __future__ import annotations

import numpy as np

from ..sh import mesh_arrays
from ..types import Camera


def _projected(mesh, camera: Camera):
    """``(triangles, colours, z [N] camera depth, uv [N, 2] pixel coordinates)`` of the mesh's
    vertices (uv of the vertices behind the camera is meaningless; callers drop them by z)."""
    pos, tri, col = mesh_arrays(mesh, camera)
    uv, z = camera.project(pos)
    return tri, col, z, uv


def _area(pa, pb, pc):
    """Twice the signed screen area of triangles ``(pa, pb, pc)`` (``[..., 2]`` each)."""
    return (pb[..., 0] - pa[..., 0]) * (pc[..., 1] - pa[..., 1]) - (pb[..., 1] - pa[..., 1]) * (pc[..., 0] - pa[..., 0])


def _barycentrics(pa, pb, pc, area, px, py):
    """Screen-space (affine) barycentric weights ``(la, lb, lc)`` of the points ``(px, py)``."""
    la = ((pb[..., 0] - px) * (pc[..., 1] - py) - (pb[..., 1] - py) * (pc[..., 0] - px)) / area
    lb = ((pc[..., 0] - px) * (pa[..., 1] - py) - (pc[..., 1] - py) * (pa[..., 0] - px)) / area
    return la, lb, 1.0 - la - lb


def mesh_raster(mesh, camera: Camera, background=(0.0, 0.0, 0.0), near=0.01, drop_near=True,
                     interpolation="perspective", edge_tol=1e-4, subpixel_bits=None, attributes_from="exact"):
    """Float64 z-buffer twin of :meth:`MeshRenderer.render` at s = 1, evaluated on pixel
    centres. Returns ``(image [H,W,3], depth [H,W] (0 = nothing), triangle id [H,W] (-1),
    ambiguous [H,W] bool)``: ambiguous where a pixel centre is within ``edge_tol`` px of an
    edge of a triangle that covers it or nearly does (the hardware's tie rule decides there),
    or where two surfaces are within 1e-5 relative depth. Triangles crossing the near plane
    are dropped (``drop_near``) or rejected with ValueError otherwise (not modelled).

    ``subpixel_bits``: rasterisers snap projected vertices to a fixed-point grid of
    ``2**-bits`` px before the coverage test (Vulkan guarantees >= 4 bits; lavapipe and the
    desktop GPUs use 8), which moves edges by up to ~``0.7 * 2**-bits`` px; give the bits to
    snap the same way for the coverage test (None: exact positions). ``attributes_from``: depth
    and colour interpolated from the ``"exact"`` positions (llvmpipe, to within float32) or the
    ``"snapped"`` ones (an NVIDIA H100: 3e-7 from this, 4e-4 from exact, 1e-2 on a sliver).
    Vulkan allows both; :func:`colour_slope` bounds how far they can differ."""
    tri, col, z, uv = _projected(mesh, camera)
    h, w = camera.height, camera.width
    img = np.empty((h, w, 3))
    img[:] = np.asarray(background, np.float64)
    inv_depth = np.zeros((h, w))
    second = np.zeros((h, w))
    tid = np.full((h, w), -1, np.int64)
    amb = np.zeros((h, w), bool)
    uv_cover = uv if subpixel_bits is None else np.round(uv * 2.0 ** subpixel_bits) / 2.0 ** subpixel_bits
    uv_attr = {"exact": uv, "snapped": uv_cover}[attributes_from]
    for t, (a, b, c) in enumerate(tri):
        if min(z[a], z[b], z[c]) <= near:
            if drop_near:
                continue
            raise ValueError("mesh_raster: near-plane clipping is not modelled; use drop_near=True")
        pa, pb, pc = uv_attr[a], uv_attr[b], uv_attr[c]
        area = _area(pa, pb, pc)
        if area == 0:
            continue
        lo = np.floor(np.minimum(np.minimum(pa, pb), pc) - 1).astype(int)
        hi = np.ceil(np.maximum(np.maximum(pa, pb), pc) + 1).astype(int)
        x0, y0 = max(lo[0], 0), max(lo[1], 0)
        x1, y1 = min(hi[0], w), min(hi[1], h)
        if x0 >= x1 or y0 >= y1:
            continue
        py, px = np.mgrid[y0:y1, x0:x1] + 0.5

        def edge(p, q):  # signed distance (px) of the centres from line p->q, positive inside for area > 0
            e = (q[0] - p[0]) * (py - p[1]) - (q[1] - p[1]) * (px - p[0])
            return e / np.hypot(q[0] - p[0], q[1] - p[1]) * np.sign(area)

        qa, qb, qc = uv_cover[a], uv_cover[b], uv_cover[c]
        ea, eb, ec = edge(qb, qc), edge(qc, qa), edge(qa, qb)
        dmin = np.minimum(np.minimum(ea, eb), ec)
        inside = dmin > 0
        near_edge = np.abs(dmin) <= edge_tol
        # screen barycentrics
        la, lb, lc = _barycentrics(pa, pb, pc, area, px, py)
        iz = la / z[a] + lb / z[b] + lc / z[c]            # 1/z is affine in screen space
        if interpolation == "linear":
            cc = la[..., None] * col[a] + lb[..., None] * col[b] + lc[..., None] * col[c]
        else:
            cc = (la[..., None] * col[a] / z[a] + lb[..., None] * col[b] / z[b] + lc[..., None] * col[c] / z[c]) \
                / iz[..., None]
        sub_amb = amb[y0:y1, x0:x1]
        sub_amb |= near_edge & (iz >= inv_depth[y0:y1, x0:x1] * (1 - 1e-3))
        win = inside & (iz > inv_depth[y0:y1, x0:x1])
        loser = inside & ~win
        sec = second[y0:y1, x0:x1]
        sec[win] = inv_depth[y0:y1, x0:x1][win]
        sec[loser] = np.maximum(sec[loser], iz[loser])
        inv_depth[y0:y1, x0:x1][win] = iz[win]
        img[y0:y1, x0:x1][win] = cc[win]
        tid[y0:y1, x0:x1][win] = t
    amb |= (second > 0) & (np.abs(inv_depth - second) <= 1e-5 * inv_depth)
    depth = np.where(inv_depth > 0, 1.0 / np.where(inv_depth > 0, inv_depth, 1.0), 0.0)
    return img, depth, tid, amb


def colour_slope(mesh, camera: Camera, tid, interpolation="perspective"):
    """Per pixel, how fast the colour of the triangle ``tid`` (a :func:`mesh_raster` id map, -1:
    none) changes across the screen at the pixel centre: ``max over channels of |dc/dx| + |dc/dy|``
    per pixel (0 where ``tid < 0``), from the exact positions. A rasteriser that moves each
    projected vertex by at most ``d`` px per coordinate (snapping to its sub-pixel grid) changes a
    pixel's interpolated colour by at most about ``slope * d``: the tolerance of the tests that
    compare hardware-drawn colours, which stays tight where colours are flat."""
    tri, col, z, uv = _projected(mesh, camera)
    out = np.zeros(tid.shape)
    r, c = np.nonzero(tid >= 0)
    if len(r) == 0:
        return out
    t = tri[tid[r, c]]
    pa, pb, pc = uv[t[:, 0]], uv[t[:, 1]], uv[t[:, 2]]
    area = _area(pa, pb, pc)
    lam = np.stack(_barycentrics(pa, pb, pc, area, c + 0.5, r + 0.5), 1)      # [K, 3]
    dlam = np.stack([np.stack([pb[:, 1] - pc[:, 1], pc[:, 1] - pa[:, 1], pa[:, 1] - pb[:, 1]], 1),
                     np.stack([pc[:, 0] - pb[:, 0], pa[:, 0] - pc[:, 0], pb[:, 0] - pa[:, 0]], 1)], 0) / area[:, None]
    cv = col[t]                                                                  # [K, 3 vertices, 3 channels]
    if interpolation == "linear":
        grad = np.einsum("dkv,kvc->dkc", dlam, cv)
    else:
        iz = 1.0 / z[t]                                                          # [K, 3]
        w = lam * iz
        wsum = w.sum(1)
        colour = np.einsum("kv,kvc->kc", w, cv) / wsum[:, None]
        dw = dlam * iz[None]
        grad = (np.einsum("dkv,kvc->dkc", dw, cv) - colour[None] * dw.sum(2)[..., None]) / wsum[None, :, None]
    out[r, c] = np.abs(grad).sum(0).max(1)
    return out
