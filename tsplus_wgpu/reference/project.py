"""Float64 twins of shaders/project/: :func:`sh_to_color` and :func:`project_triangles`,
and :func:`projection` (both for a model and a camera, as a :class:`Projection`).

The model (method.md):
  * vertex colour ``c_v = max(0, SH(dir_v) + 0.5)``, dir_v the unit vector from the
    camera centre to the vertex (zero at the centre itself: DC only);
  * a triangle with any vertex at camera z <= near is not drawn; nor one whose
    opacity o_T = min of its vertices' is below 1/255 (it could never reach alpha 1/255),
    nor one numerically degenerate on screen (2*area / perimeter^2 < 1e-6);
  * window ``I(p) = max(0, phi(p)/phi(s))^sigma`` with ``phi(p)/phi(s) = min_k e_k(p)``,
    ``e_k(p) = 1 + g_k . (p - s)``, s the incenter, g_k = -n_k / r;
  * colour at p: screen-space barycentric interpolation, b_k = e_k(p) len_k / perimeter.
The constants are the WGSL's (``shaders/common/frame.wgsl``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from ..gpu.wgsl import SHADER_DIR, constant, struct_dtype
from ..sh import vertex_colors
from ..types import Camera, TriangleModel

TILE = constant("TILE", "frame")
ALPHA_MIN = constant("ALPHA_MIN", "frame")
ALPHA_MAX = constant("ALPHA_MAX", "frame")
T_MIN = constant("T_MIN", "frame")
MIN_THINNESS = constant("MIN_THINNESS", "frame")
BIN_MARGIN = constant("BIN_MARGIN", "frame")


def _tri2d_dtype():
    """Float64 twin of the WGSL ``Tri2D`` record: the same field names and shapes."""
    code = (SHADER_DIR / "common" / "triangle.wgsl").read_text()
    f32 = struct_dtype(re.search(r"struct\s+Tri2D\s*\{([^}]*)\}", code, re.S).group(1), {})
    return np.dtype([(name, np.float64, f32[name].shape) for name in f32.names])


#: the ``Tri2D`` record (shaders/common/triangle.wgsl) in float64: s, opacity, tau, g0..g2, depth, inradius,
#: color, dcolor_dx, dcolor_dy (the colour fields are vec4, w = 0)
TRI2D = _tri2d_dtype()


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


def sh_to_color(positions, sh, cam_center):
    """Twin of sh_to_color: ``colors [N, 4]`` = (max(0, SH(dir) + 0.5), 1) for ``positions [N, 3]``,
    ``sh [N, K, 3]`` (K = the uniform's sh_k) and the uniform's ``cam_center [3]``."""
    rgb = vertex_colors(np.asarray(positions, np.float64), np.asarray(sh, np.float64),
                        np.asarray(cam_center, np.float64))
    return np.concatenate([rgb, np.ones((rgb.shape[0], 1))], axis=1)


def project_triangles(positions, triangles, opacities, colors, R, t, fx, fy, cx, cy, near, sigma, width, height):
    """Twin of project_triangles.

    Args:
        positions [N, 3], triangles [M, 3], opacities [N], colors [N, 3 or 4] (the kernel reads xyz);
        the uniform's fields: ``R [3, 3]``, ``t [3]`` (x_cam = R x + t), fx, fy, cx, cy, near, sigma,
        width, height.

    Returns:
        ``(tris [M] TRI2D, pixel_rects [M, 4] int64, depth_keys [M] uint32, tri_ids [M] uint32)``;
        a culled triangle has a zero record, the box (1, 1, 0, 0) and the key 0xFFFFFFFF. The key
        of a drawn one is the bit pattern of its float32-rounded depth (the kernel's float32 depth).
    """
    proj = _project(positions, triangles, opacities, np.asarray(colors, np.float64)[:, :3], R, t, fx, fy, cx, cy,
                    width, height, sigma, near)
    m = proj.visible.shape[0]
    v = proj.visible
    tris = np.zeros(m, TRI2D)
    for name, value in (("s", proj.s), ("opacity", proj.opacity), ("tau", proj.tau), ("g0", proj.g[:, 0]),
                        ("g1", proj.g[:, 1]), ("g2", proj.g[:, 2]), ("depth", proj.depth),
                        ("inradius", proj.inradius)):
        tris[name][v] = value[v]
    for name, value in (("color", proj.color), ("dcolor_dx", proj.dcolor_dx), ("dcolor_dy", proj.dcolor_dy)):
        tris[name][v, :3] = value[v]
    depth_keys = np.full(m, 0xFFFFFFFF, np.uint32)
    depth_keys[v] = proj.depth[v].astype(np.float32).view(np.uint32)
    return tris, proj.rect, depth_keys, np.arange(m, dtype=np.uint32)


def projection(model: TriangleModel, camera: Camera, sigma, near=0.01):
    """:func:`sh_to_color` then :func:`project_triangles` for a model and a camera, as a
    :class:`Projection` (with the vertices on screen and their colours, for the other twins)."""
    colors = vertex_colors(model.positions, model.sh, camera.center)
    return _project(model.positions, model.triangles, model.opacity, colors, camera.R, camera.t, camera.fx,
                    camera.fy, camera.cx, camera.cy, camera.width, camera.height, sigma, near)


def _project(positions, tri, opacities, colors, R, t, fx, fy, cx, cy, width, height, sigma, near):
    xc = np.asarray(positions, np.float64) @ np.asarray(R).T + np.asarray(t)    # [N, 3]
    tri = np.asarray(tri)
    m = tri.shape[0]
    z = xc[tri, 2]                                                  # [M, 3]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        uv = np.stack([fx * xc[:, 0] / xc[:, 2] + cx, fy * xc[:, 1] / xc[:, 2] + cy], axis=1)
        p = uv[tri]                                                 # [M, 3, 2]
        visible = np.all(z > near, axis=1)
        opacity = np.asarray(opacities)[tri].min(axis=1)
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
        lim = np.array([width, height], dtype=np.float64)
        plo = np.clip(np.ceil(lo - 0.5), -1, lim)
        phi = np.clip(np.floor(hi - 0.5), -1, lim)
    plo = np.nan_to_num(plo, nan=1.0)
    phi = np.nan_to_num(phi, nan=0.0)
    rect = np.stack([np.maximum(plo[:, 0], 0), np.maximum(plo[:, 1], 0),
                     np.minimum(phi[:, 0], width - 1), np.minimum(phi[:, 1], height - 1)], axis=1).astype(np.int64)
    visible &= (rect[:, 0] <= rect[:, 2]) & (rect[:, 1] <= rect[:, 3])
    rect[~visible] = (1, 1, 0, 0)
    vcol = np.asarray(colors, np.float64)[tri]                       # [M, 3, 3]
    wts = lengths / perim_safe[:, None]                             # barycentrics at s
    color = np.einsum("mk,mkc->mc", wts, vcol)
    dcdx = np.einsum("mk,mk,mkc->mc", wts, g[:, :, 0], vcol)
    dcdy = np.einsum("mk,mk,mkc->mc", wts, g[:, :, 1], vcol)
    return Projection(visible=visible, verts2d=p, s=s, g=g, lengths=lengths, inradius=r, opacity=opacity,
                      tau=tau, depth=z.mean(axis=1), vcolors=vcol, rect=rect, color=color, dcolor_dx=dcdx,
                      dcolor_dy=dcdy)


def projection_from_records(records, rects):
    """A :class:`Projection` from Tri2D records (structured array [M], the kernel's or
    :func:`project_triangles`') and pixel boxes [M, 4], so the blend twin can run on exactly
    the kernel's inputs."""
    rects = np.asarray(rects, np.int64)
    visible = (rects[:, 0] <= rects[:, 2]) & (rects[:, 1] <= rects[:, 3])
    f = lambda name: np.asarray(records[name], np.float64)
    g = np.stack([f("g0"), f("g1"), f("g2")], axis=1)
    return Projection(visible=visible, verts2d=None, s=f("s"), g=g, lengths=None, inradius=f("inradius"),
                      opacity=f("opacity"), tau=f("tau"), depth=f("depth"), vcolors=None, rect=rects,
                      color=f("color")[:, :3], dcolor_dx=f("dcolor_dx")[:, :3], dcolor_dy=f("dcolor_dy")[:, :3])
