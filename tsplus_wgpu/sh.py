"""Host-side spherical harmonics: the real SH basis and per-vertex colours (float64 NumPy),
for the mesh renderer, export and the viewer; also the twin of ``shaders/project/sh_to_color``."""

from __future__ import annotations

import numpy as np

from .types import SH_C0, TriangleModel


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


def mesh_arrays(mesh, camera=None):
    """(positions [N,3], triangles [M,3], colors [N,3]) from a TriangleModel (colour
    max(0, SH(dir) + 0.5) for ``camera``, as the splatting model), or a (positions,
    triangles, colors) triple."""
    if isinstance(mesh, TriangleModel):
        if mesh.sh_size == 1 or camera is None:
            col = np.maximum(mesh.sh[:, 0] * SH_C0 + 0.5, 0.0)
        else:
            col = vertex_colors(mesh.positions, mesh.sh, camera.center)
        return mesh.positions, mesh.triangles, col
    try:
        pos, tri, col = mesh
    except Exception:
        raise ValueError("mesh: expected a TriangleModel or a (positions, triangles, colors) triple") from None
    pos = np.asarray(pos, np.float64)
    tri = np.asarray(tri)
    col = np.asarray(col, np.float64)
    if pos.ndim != 2 or pos.shape[1] != 3:
        raise ValueError(f"positions: expected shape [N, 3], got {pos.shape}")
    if tri.ndim != 2 or tri.shape[1] != 3:
        raise ValueError(f"triangles: expected shape [M, 3], got {tri.shape}")
    if col.shape != pos.shape:
        raise ValueError(f"colors: expected shape {pos.shape}, got {col.shape}")
    if tri.size and (tri.min() < 0 or tri.max() >= len(pos)):
        raise ValueError(f"triangles: index out of range [0, {len(pos)})")
    if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(col))):
        raise ValueError("mesh: non-finite positions or colours")
    return pos, tri.astype(np.int64), col
