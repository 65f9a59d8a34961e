"""The procedural scene's reference rasteriser: a vectorised NumPy z-buffer with near-plane
clipping and perspective-correct interpolation of the 3D surface point (float64)."""

from __future__ import annotations

import numpy as np

from ..types import Camera

NEAR = 0.02


def _clip_near(pc, pw, fid, near):
    """Clip triangles (camera coords ``pc [T,3,3]``, world coords ``pw``) against z = near."""
    inside = pc[:, :, 2] >= near
    cnt = inside.sum(1)
    out_c, out_w, out_f = [pc[cnt == 3]], [pw[cnt == 3]], [fid[cnt == 3]]

    def roll(arr, k):
        idx = (k[:, None] + np.arange(3)[None]) % 3
        return np.take_along_axis(arr, idx[:, :, None], axis=1)

    def lerp(a, b, za, zb):
        t = ((near - za) / (zb - za))[:, None]
        return a + (b - a) * t

    one = cnt == 1
    if np.any(one):
        k = np.argmax(inside[one], axis=1)
        c, w = roll(pc[one], k), roll(pw[one], k)
        z = c[:, :, 2]
        nc = np.stack([c[:, 0], lerp(c[:, 0], c[:, 1], z[:, 0], z[:, 1]), lerp(c[:, 0], c[:, 2], z[:, 0], z[:, 2])], 1)
        nw = np.stack([w[:, 0], lerp(w[:, 0], w[:, 1], z[:, 0], z[:, 1]), lerp(w[:, 0], w[:, 2], z[:, 0], z[:, 2])], 1)
        out_c.append(nc)
        out_w.append(nw)
        out_f.append(fid[one])
    two = cnt == 2
    if np.any(two):
        k = np.argmin(inside[two], axis=1)  # the outside vertex first
        c, w = roll(pc[two], k), roll(pw[two], k)
        z = c[:, :, 2]
        cb, cc = lerp(c[:, 0], c[:, 1], z[:, 0], z[:, 1]), lerp(c[:, 0], c[:, 2], z[:, 0], z[:, 2])
        wb, wc = lerp(w[:, 0], w[:, 1], z[:, 0], z[:, 1]), lerp(w[:, 0], w[:, 2], z[:, 0], z[:, 2])
        out_c += [np.stack([cb, c[:, 1], c[:, 2]], 1), np.stack([cb, c[:, 2], cc], 1)]
        out_w += [np.stack([wb, w[:, 1], w[:, 2]], 1), np.stack([wb, w[:, 2], wc], 1)]
        out_f += [fid[two], fid[two]]
    return np.concatenate(out_c), np.concatenate(out_w), np.concatenate(out_f)


def rasterize(verts, faces, cam: Camera, ss: int = 1, near: float = NEAR, chunk: int = 2_000_000,
              cull_backfaces: bool = True):
    """Z-buffer rasterisation of a triangle mesh with a pinhole camera.

    Args:
        verts: ``[V,3]`` world positions; faces: ``[F,3]`` indices (counter-clockwise seen from the
            visible side when ``cull_backfaces``).
        cam: the camera; the image is rendered at ``ss`` times its size (pixel centres of the
            supersampled grid at +0.5 of its own pixels).
        near: near clipping plane (camera-space z).

    Returns:
        ``(face [H,W] int64 (-1 = empty), depth [H,W] float64 camera z (inf = empty),
        point [H,W,3] float64 world position of the visible surface)`` at the supersampled size.
    """
    W, H = cam.width * ss, cam.height * ss
    fx, fy, cx, cy = cam.fx * ss, cam.fy * ss, cam.cx * ss, cam.cy * ss
    pw = verts[faces]                                   # [F,3,3]
    fid = np.arange(len(faces))
    if cull_backfaces:
        n = np.cross(pw[:, 1] - pw[:, 0], pw[:, 2] - pw[:, 0])
        vis = np.einsum("ij,ij->i", n, cam.center - pw[:, 0]) > 0
        pw, fid = pw[vis], fid[vis]
    pc = pw @ cam.R.T + cam.t                            # [T,3,3]
    pc, pw, fid = _clip_near(pc, pw, fid, near)
    z = pc[:, :, 2]
    sx = fx * pc[:, :, 0] / z + cx
    sy = fy * pc[:, :, 1] / z + cy
    x0 = np.clip(np.ceil(sx.min(1) - 0.5), 0, W).astype(np.int64)
    x1 = np.clip(np.floor(sx.max(1) - 0.5), -1, W - 1).astype(np.int64)
    y0 = np.clip(np.ceil(sy.min(1) - 0.5), 0, H).astype(np.int64)
    y1 = np.clip(np.floor(sy.max(1) - 0.5), -1, H - 1).astype(np.int64)
    nx, ny = np.maximum(x1 - x0 + 1, 0), np.maximum(y1 - y0 + 1, 0)
    area = (sx[:, 1] - sx[:, 0]) * (sy[:, 2] - sy[:, 0]) - (sx[:, 2] - sx[:, 0]) * (sy[:, 1] - sy[:, 0])
    live = np.nonzero((nx > 0) & (ny > 0) & (np.abs(area) > 1e-12))[0]
    zbuf = np.full(H * W, np.inf)
    fbuf = np.full(H * W, -1, np.int64)
    pbuf = np.zeros((H * W, 3))
    counts = (nx * ny)[live]
    bounds = np.searchsorted(np.cumsum(counts), np.arange(chunk, counts.sum() + chunk, chunk))
    tris = (sx, sy, z, area, x0, y0, nx, ny, pw, fid)
    start = 0
    for stop in list(bounds) + [len(live)]:
        stop = max(stop + 1, start + 1) if stop < len(live) else len(live)
        idx = live[start:stop]
        start = stop
        if len(idx):
            _raster_chunk(idx, tris, W, zbuf, fbuf, pbuf)
    return fbuf.reshape(H, W), zbuf.reshape(H, W), pbuf.reshape(H, W, 3)


def _raster_chunk(idx, tris, W, zbuf, fbuf, pbuf):
    """Rasterise the triangles ``idx`` (screen-space data ``tris``) into the flat z / face /
    point buffers of width ``W``: every covered pixel centre of their rectangles, nearest wins."""
    sx, sy, z, area, x0, y0, nx, ny, pw, fid = tris
    cnt = nx[idx] * ny[idx]
    rep = np.repeat(np.arange(len(idx)), cnt)
    local = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    t = idx[rep]
    jj = x0[t] + local % nx[t]
    ii = y0[t] + local // nx[t]
    px, py = jj + 0.5, ii + 0.5
    ax, ay = sx[t, 0], sy[t, 0]
    bx, by = sx[t, 1], sy[t, 1]
    qx, qy = sx[t, 2], sy[t, 2]
    a = area[t]
    w0 = ((bx - px) * (qy - py) - (qx - px) * (by - py)) / a
    w1 = ((qx - px) * (ay - py) - (ax - px) * (qy - py)) / a
    w2 = 1.0 - w0 - w1
    ok = (w0 >= 0) & (w1 >= 0) & (w2 >= 0)
    if not np.any(ok):
        return
    t, jj, ii, w0, w1, w2 = t[ok], jj[ok], ii[ok], w0[ok], w1[ok], w2[ok]
    iz = w0 / z[t, 0] + w1 / z[t, 1] + w2 / z[t, 2]
    depth = 1.0 / iz
    pid = ii * W + jj
    # one float sort key: pixel id + depth mapped into [0, 1) (monotonic in depth)
    order = np.argsort(pid + depth / (depth + 1.0), kind="stable")
    pid_s = pid[order]
    first = np.ones(len(order), bool)
    first[1:] = pid_s[1:] != pid_s[:-1]
    win = order[first]
    pid_w = pid[win]
    better = depth[win] < zbuf[pid_w]
    win, pid_w = win[better], pid_w[better]
    b0 = (w0[win] / z[t[win], 0] * depth[win])[:, None]
    b1 = (w1[win] / z[t[win], 1] * depth[win])[:, None]
    b2 = 1.0 - b0 - b1
    zbuf[pid_w] = depth[win]
    fbuf[pid_w] = fid[t[win]]
    pbuf[pid_w] = b0 * pw[t[win], 0] + b1 * pw[t[win], 1] + b2 * pw[t[win], 2]
