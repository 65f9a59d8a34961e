"""Float64 twins of shaders/normals/ (one function per kernel, same name) and of the whole
normal loss (:func:`normal_loss`: normal_model -> forward -> backward -> normal_backward ->
per-vertex sum -> normal_accumulate; :func:`normal_loss_value`: the loss alone)."""

from __future__ import annotations

import numpy as np

from ..types import SH_C0, Camera, TriangleModel
from .optim import min_corner

#: the two gradient paths of the normal loss: through the blending weights, through the 3D normal
PATHS = ("alpha", "normal")


def triangle_normals(positions, triangles, camera: Camera):
    """Per triangle ``(n [M, 3] camera space, facing the camera; u [M, 3] world unit normal;
    length [M] = |cross|; sign [M] = +-1)`` float64 (twin of ``common/normal.wgsl``)."""
    x = np.asarray(positions, np.float64)[np.asarray(triangles, np.int64)]         # [M, 3, 3]
    e = np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0])
    length = np.sqrt(np.einsum("mi,mi->m", e, e))
    ok = length > 0
    u = np.where(ok[:, None], e / np.where(ok, length, 1.0)[:, None], 0.0)
    R, t = camera.R, camera.t
    n = u @ R.T
    c = x.mean(axis=1) @ R.T + t
    sign = np.where(np.einsum("mi,mi->m", n, c) > 0, -1.0, 1.0)
    return sign[:, None] * n, u, np.where(ok, length, 0.0), sign


def normal_model(model: TriangleModel, camera: Camera) -> TriangleModel:
    """The unshared normal render model (twin of ``normal_model.wgsl``): corners ``3t + k`` at
    the triangles' vertices, SH DC ``n_t / (2 SH_C0)`` (degree 0), opacity ``o_T``."""
    tri = model.triangles
    m = tri.shape[0]
    n, _, _, _ = triangle_normals(model.positions, tri, camera)
    pos = model.positions[tri].reshape(3 * m, 3)
    sh = np.repeat(n / (2.0 * SH_C0), 3, axis=0)[:, None, :]
    op = np.repeat(model.opacity[tri].min(axis=1), 3)
    return TriangleModel(pos, np.arange(3 * m).reshape(m, 3), sh, op)


def normal_backward(positions, triangles, opacity, camera: Camera, v_corner_positions, v_corner_sh,
                    v_corner_opacity, paths=PATHS):
    """``corner_vals [3M, 4]`` float64: per corner of the shared model, d position (xyz) and
    d opacity (w) from the normal model's corner gradients ``v_corner_positions [3M, 3]``,
    ``v_corner_sh [3M, 1, 3]``, ``v_corner_opacity [3M]``. ``paths``: which gradient paths to
    keep, ``"alpha"`` (the corner positions, o_T to the vertex holding the minimum) and
    ``"normal"`` (through the 3D normal); both for the kernel."""
    bad = set(paths) - set(PATHS)
    if bad:
        raise ValueError(f"paths: unknown {sorted(bad)}; expected a subset of {PATHS}")
    x = np.asarray(positions, np.float64)
    tri = np.asarray(triangles, np.int64).reshape(-1, 3)
    m = len(tri)
    out = np.zeros((m, 3, 4))
    if "alpha" in paths:
        out[:, :, :3] += np.asarray(v_corner_positions, np.float64).reshape(m, 3, 3)
        v_ot = np.asarray(v_corner_opacity, np.float64).reshape(m, 3).sum(axis=1)
        out[np.arange(m), min_corner(tri, np.asarray(opacity, np.float64)), 3] = v_ot
    if "normal" in paths:
        v_n = np.asarray(v_corner_sh, np.float64).reshape(m, 3, 3).sum(axis=1) / (2.0 * SH_C0)   # [M, 3]
        _, u, length, sign = triangle_normals(x, tri, camera)
        ok = length > 0
        v_u = sign[:, None] * (v_n @ camera.R)                                     # R^T v_n
        v_e = (v_u - u * np.einsum("mi,mi->m", u, v_u)[:, None]) / np.where(ok, length, 1.0)[:, None]
        v_e[~ok] = 0.0
        xt = x[tri]
        g1 = np.cross(xt[:, 2] - xt[:, 0], v_e)
        g2 = np.cross(v_e, xt[:, 1] - xt[:, 0])
        out[:, :, :3] += np.stack([-(g1 + g2), g1, g2], axis=1)
    return out.reshape(3 * m, 4)


def normal_accumulate(vertex_sums, v_positions, v_opacity, weight):
    """``(v_positions + weight sums.xyz [N, 3], v_opacity + weight sums.w [N])`` float64."""
    s = float(weight) * np.asarray(vertex_sums, np.float64).reshape(-1, 4)
    return (np.asarray(v_positions, np.float64).reshape(-1, 3) + s[:, :3],
            np.asarray(v_opacity, np.float64).reshape(-1) + s[:, 3])


def normal_render(model: TriangleModel, camera: Camera, sigma, near=0.01):
    """``(N [H, W, 3], T [H, W])``: the alpha-blended camera-space normal and the final
    transmittance, float64, through :func:`tsplus_wgpu.reference.render` of the normal model."""
    from .forward import render     # the forward twin
    r = render(normal_model(model, camera), camera, sigma, (0.0, 0.0, 0.0), near)
    return 2.0 * r.image - (1.0 - r.transmittance)[..., None], r.transmittance


def normal_loss_value(model, camera, sigma, prior, valid, weight=1.0, near=0.01):
    """``weight * mean over valid pixels of (1 - <N, P>)`` (0 when no pixel is valid), float64."""
    v = np.asarray(valid, bool)
    if not v.any():
        return 0.0
    n, _ = normal_render(model, camera, sigma, near)
    return float(weight) * float(np.mean(1.0 - np.einsum("pc,pc->p", n[v], np.asarray(prior, np.float64)[v])))


def normal_loss(model: TriangleModel, camera: Camera, sigma, prior, valid, weight=1.0, near=0.01, paths=PATHS):
    """Float64 twin of the whole normal-loss gradient (normal_model -> forward -> backward ->
    normal_backward -> per-vertex sum -> normal_accumulate).

    Args:
        model, camera, sigma, near: as for :func:`tsplus_wgpu.reference.render`.
        prior, valid: from :func:`tsplus_wgpu.data.normals.prepare_prior`.
        weight: the loss weight.
        paths: the gradient paths to keep (see :func:`normal_backward`). Both for the true
            gradient; one alone only for tests that show the other matters.

    Returns:
        ``(loss, v_positions [N, 3], v_opacity [N])`` float64.
    """
    from .render_backward import backward   # the backward twin
    tri = model.triangles
    m, nv = tri.shape[0], model.num_vertices
    p = np.asarray(prior, np.float64)
    v = np.asarray(valid, bool)
    cnt = int(v.sum())
    if cnt == 0 or m == 0:
        return 0.0, np.zeros((nv, 3)), np.zeros(nv)
    # d mean(1 - <N, P>) / d (C, T) with N = 2 C - (1 - T)
    v_image = np.where(v[..., None], -2.0 * p / cnt, 0.0)
    v_t = np.where(v, -p.sum(axis=2) / cnt, 0.0)
    um = normal_model(model, camera)
    g = backward(um, camera, sigma, v_image, v_t, (0.0, 0.0, 0.0), near)
    corner = normal_backward(model.positions, tri, model.opacity, camera, g.v_positions, g.v_sh, g.v_opacity, paths)
    sums = np.zeros((nv, 4))
    np.add.at(sums, tri.ravel(), corner)
    v_pos, v_op = normal_accumulate(sums, np.zeros((nv, 3)), np.zeros(nv), weight)
    return normal_loss_value(model, camera, sigma, prior, valid, weight, near), v_pos, v_op


__all__ = ["PATHS", "triangle_normals", "normal_model", "normal_backward", "normal_accumulate", "normal_render",
           "normal_loss_value", "normal_loss"]
