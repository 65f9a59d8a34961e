"""Float64 twin of the backward pass: the exact derivative of :func:`reference.render`.

The loss is ``L = sum(v_image * image) + sum(v_transmittance * T)``; the function returns
dL/d(positions, sh, opacity). Every term of the forward model as defined is kept:

* screen position -> pixels through the full pinhole Jacobian (fx/z, fy/z and the
  perspective terms in z), then ``R^T`` to world space;
* the window ratio ``min_k e_k(p)`` with ``e_k = b_k(p) * perimeter / len_k`` depends on
  all three 2D vertices through the barycentrics, the side lengths and the perimeter,
  i.e. through the incenter and the inradius (phi(s) = -r);
* the colour ``c(p) = sum_k c_k b_k(p)`` (screen-space barycentrics) gives gradients to
  the vertex colours *and* to the 2D positions;
* the vertex colour ``max(0, SH(dir) + 0.5)`` gives gradients to the SH coefficients and,
  through ``dir = (x - centre) / |x - centre|``, to the positions (zero where clamped);
* ``alpha = min(0.99, o I)``: where the cap is active alpha does not depend on o or I;
* ``o_T = min(o_i, o_j, o_k)``: the gradient goes to the vertex holding the minimum; on a
  tie, to the tied vertex with the lowest (global) vertex index.

Discrete decisions (culling, depth order, tiles, the 1/255 skip, the T < 1e-4 stop,
argmin of the edges) are piecewise constant and have zero derivative; ties in the edge
argmin go to the lowest edge index.
"""

from __future__ import annotations


import numpy as np

from . import forward as ref
from .backward import min_vertex, vertex_backward
from ..types import Camera, TriangleModel
from ..types import Grads, check_cotangents


def _cross(a, b):
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _perp(a):  # d cross(a, b) / d b = perp(a) ; d cross(a, b) / d a = -perp(b)
    return np.stack([-a[..., 1], a[..., 0]], axis=-1)


def backward(model: TriangleModel, camera: Camera, sigma, v_image, v_transmittance=None,
             background=(0.0, 0.0, 0.0), near=0.01) -> Grads:
    """Gradients of ``sum(v_image * image) + sum(v_transmittance * T)`` of
    :func:`reference.render` with respect to the model's positions, SH and opacities.

    Args:
        model, camera, sigma, background, near: as for :func:`reference.render`.
        v_image: ``[H, W, 3]`` dL/d image.
        v_transmittance: ``[H, W]`` dL/d final transmittance, or None (zero).

    Returns:
        :class:`Grads` (float64).
    """
    sigma, bg, near = ref.check_render_args(sigma, background, near)
    if not isinstance(model, TriangleModel):
        raise ValueError("model: expected a TriangleModel")
    if not isinstance(camera, Camera):
        raise ValueError("camera: expected a Camera")
    h, w = camera.height, camera.width
    vi, vt = check_cotangents(v_image, v_transmittance, h, w)
    proj = ref.projection(model, camera, sigma, near)
    order = ref.depth_order(proj)
    fwd = ref.blend(proj, order, w, h, sigma, bg)
    # Z = the pixel's whole loss; Z - (colour accumulated up to j) . v = what lies behind j.
    Z = np.einsum("hwc,hwc->hw", fwd.image, vi) + fwd.transmittance * vt

    m = model.num_triangles
    v_A = np.zeros((m, 3, 2))        # d/d 2D vertex positions (pixels)
    v_vcol = np.zeros((m, 3, 3))     # d/d vertex colours
    v_otri = np.zeros(m)             # d/d triangle opacity
    T = np.ones((h, w))
    acc = np.zeros((h, w))           # (C accumulated so far) . v_image
    done = np.zeros((h, w), bool)
    for t in order:
        if not proj.visible[t]:
            continue
        px = _blend_triangle(proj, t, sigma, vi, Z, T, acc, done)
        if px is None:
            continue
        v_otri[t] += px["v_o"]
        gA, v_vcol[t] = _triangle_grads(proj, t, px)
        v_A[t] += gA
    return _to_vertices(model, camera, proj, v_A, v_vcol, v_otri)


def _blend_triangle(proj, t, sigma, vi, Z, T, acc, done):
    """Triangle ``t`` in the blend: updates ``T``, ``acc``, ``done`` in place; returns the
    pixels it contributes to with what the chain rule needs (None: no pixel)."""
    x0, y0, x1, y1 = proj.rect[t]
    ys, xs = np.mgrid[y0:y1 + 1, x0:x1 + 1]
    d = np.stack([xs + 0.5 - proj.s[t, 0], ys + 0.5 - proj.s[t, 1]], axis=-1)
    e = 1.0 + d @ proj.g[t].T
    ratio = e.min(axis=-1)
    live = ~done[y0:y1 + 1, x0:x1 + 1]
    o = proj.opacity[t]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        pos = np.maximum(ratio, 1e-300)
        win = np.where(ratio > 0, np.power(pos, sigma), 0.0)
    alpha = np.minimum(ref.ALPHA_MAX, o * win)
    valid = live & (ratio > 0) & (alpha >= ref.ALPHA_MIN)
    Tloc = T[y0:y1 + 1, x0:x1 + 1]
    nxt = Tloc * (1.0 - alpha)
    stop = valid & (nxt < ref.T_MIN)
    contrib = valid & ~stop
    done[y0:y1 + 1, x0:x1 + 1] |= stop
    if not contrib.any():
        return None
    iy, ix = np.nonzero(contrib)
    a = alpha[iy, ix]
    Tj = Tloc[iy, ix]
    r_ = ratio[iy, ix]
    win_ = win[iy, ix]
    vpix = vi[y0 + iy, x0 + ix]                                           # [P, 3]
    col = proj.color[t] + d[iy, ix, :1] * proj.dcolor_dx[t] + d[iy, ix, 1:] * proj.dcolor_dy[t]
    cv = np.einsum("pc,pc->p", col, vpix)
    acc_loc = acc[y0 + iy, x0 + ix] + cv * a * Tj
    acc[y0 + iy, x0 + ix] = acc_loc
    T[y0 + iy, x0 + ix] = Tj * (1.0 - a)
    v_a = Tj * cv - (Z[y0 + iy, x0 + ix] - acc_loc) / (1.0 - a)
    active = o * win_ < ref.ALPHA_MAX
    v_ratio = np.where(active, v_a * o * sigma * win_ / r_, 0.0)
    kmin = np.argmin(e[iy, ix], axis=-1)                                  # ties: lowest edge
    return dict(iy=iy + y0, ix=ix + x0, a=a, Tj=Tj, vpix=vpix, v_ratio=v_ratio, kmin=kmin,
                v_o=np.sum(np.where(active, v_a * win_, 0.0)))


def _triangle_grads(proj, t, px):
    """Triangle ``t``'s contributions through the exact barycentrics b_k = N_k(p) / D:
    ([3, 2] dL/d 2D vertices, [3, 3] dL/d vertex colours)."""
    a, Tj, vpix, v_ratio, kmin = px["a"], px["Tj"], px["vpix"], px["v_ratio"], px["kmin"]
    v_vcol = np.zeros((3, 3))
    A = proj.verts2d[t]                                                   # [3, 2]
    p = np.stack([px["ix"] + 0.5, px["iy"] + 0.5], axis=-1).astype(np.float64)   # [P, 2]
    E1, E2 = A[1] - A[0], A[2] - A[0]
    D = _cross(E1, E2)
    lens = proj.lengths[t]
    P = lens.sum()
    v_colp = (a * Tj)[:, None] * vpix                                     # dL/dc(p)  [P, 3]
    v_D = 0.0
    v_P = 0.0
    v_l = np.zeros(3)
    gA = np.zeros((3, 2))
    for k in range(3):
        U, V = A[(k + 1) % 3], A[(k + 2) % 3]
        Nk = _cross(U[None, :] - p, V[None, :] - p)                       # [P]
        bk = Nk / D
        v_vcol[k] += np.einsum("p,pc->c", bk, v_colp)
        sel = np.where(kmin == k, v_ratio, 0.0)
        v_b = v_colp @ proj.vcolors[t, k] + sel * P / lens[k]
        v_P += np.sum(sel * bk) / lens[k]
        v_l[k] -= np.sum(sel * bk) * P / lens[k] ** 2
        v_N = v_b / D
        v_D -= np.sum(v_b * bk) / D
        # N_k = cross(U - p, V - p)
        gA[(k + 1) % 3] += np.einsum("p,pi->i", v_N, -_perp(V[None, :] - p))
        gA[(k + 2) % 3] += np.einsum("p,pi->i", v_N, _perp(U[None, :] - p))
    # D = cross(E1, E2)
    gA[1] += v_D * -_perp(E2)
    gA[2] += v_D * _perp(E1)
    gA[0] -= v_D * (-_perp(E2) + _perp(E1))
    v_l += v_P
    for k in range(3):
        i, j = (k + 1) % 3, (k + 2) % 3
        u = (A[i] - A[j]) / lens[k]
        gA[i] += v_l[k] * u
        gA[j] -= v_l[k] * u
    return gA, v_vcol


def _to_vertices(model, camera, proj, v_A, v_vcol, v_otri):
    n = model.num_vertices
    tri = model.triangles
    m = tri.shape[0]
    v_uv = np.zeros((n, 2))
    v_c = np.zeros((n, 3))
    v_op = np.zeros(n)
    np.add.at(v_uv, tri.ravel(), v_A.reshape(-1, 2))
    np.add.at(v_c, tri.ravel(), v_vcol.reshape(-1, 3))
    if m:
        np.add.at(v_op, tri[np.arange(m), min_vertex(model.opacity, tri)], v_otri)
    # pinhole: u = fx X/Z + cx, v = fy Y/Z + cy
    R, t = camera.R, camera.t
    xc = model.positions @ R.T + t
    X, Y, Zc = xc[:, 0], xc[:, 1], xc[:, 2]
    used = np.any(v_uv != 0, axis=1)
    Zs = np.where(used, Zc, 1.0)
    v_xc = np.stack([v_uv[:, 0] * camera.fx / Zs, v_uv[:, 1] * camera.fy / Zs,
                     -(v_uv[:, 0] * camera.fx * X + v_uv[:, 1] * camera.fy * Y) / (Zs * Zs)], axis=1)
    v_xc[~used] = 0.0
    v_pos = v_xc @ R
    # colour = max(0, SH(dir) . sh + 0.5): the twin of vertex_backward
    sums = np.zeros((n, 2, 4))
    sums[:, 0, :3], sums[:, 0, 3], sums[:, 1, :3] = v_c, v_op, v_pos
    v_pos, v_sh, v_op = vertex_backward(model.positions, model.sh, sums, camera.center)
    return Grads(v_positions=v_pos, v_sh=v_sh, v_opacity=v_op)


def loss(model, camera, sigma, v_image, v_transmittance=None, background=(0.0, 0.0, 0.0), near=0.01):
    """The scalar whose gradient :func:`backward` returns (for finite differences)."""
    r = ref.render(model, camera, sigma, background, near)
    out = float(np.sum(r.image * v_image))
    if v_transmittance is not None:
        out += float(np.sum(r.transmittance * v_transmittance))
    return out
