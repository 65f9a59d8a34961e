"""Public value types: :class:`Camera` and :class:`TriangleModel`.

Both validate their inputs on construction and raise a one-line ``ValueError``
naming the offending argument, so bad data never reaches the device.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SH_SIZES = (1, 4, 9, 16)


def _finite_array(name, value, dtype, shape_desc, ndim=None):
    try:
        arr = np.asarray(value)
    except Exception as exc:  # pragma: no cover - exotic inputs
        raise ValueError(f"{name}: cannot be read as an array ({exc})") from None
    if arr.dtype == object:
        raise ValueError(f"{name}: expected a numeric array {shape_desc}, got objects")
    if ndim is not None and arr.ndim != ndim:
        raise ValueError(f"{name}: expected shape {shape_desc}, got {arr.shape}")
    if np.issubdtype(dtype, np.floating):
        if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
            raise ValueError(f"{name}: expected a float array, got dtype {arr.dtype}")
        arr = arr.astype(dtype, copy=False)
        if arr.size and not np.all(np.isfinite(arr)):
            bad = int(np.size(arr) - np.count_nonzero(np.isfinite(arr)))
            raise ValueError(f"{name}: {bad} non-finite value(s) (NaN or Inf); clean the input first")
    return arr


class Camera:
    """A pinhole camera in the COLMAP/OpenCV convention.

    Args:
        width, height: image size in pixels (both >= 1).
        fx, fy, cx, cy: intrinsics in pixels; the centre of pixel (row i, col j)
            is at (j + 0.5, i + 0.5).
        world_to_camera: 4x4 matrix, ``x_cam = R x_world + t``; the camera looks
            down +z with y pointing down.
    """

    def __init__(self, width, height, fx, fy, cx, cy, world_to_camera):
        for name, v in (("width", width), ("height", height)):
            if isinstance(v, bool) or not float(v).is_integer():
                raise ValueError(f"Camera {name}: must be a whole number of pixels, got {v!r}")
            if int(v) < 1:
                raise ValueError(f"Camera {name}: must be >= 1 pixel, got {v!r}")
        self.width = int(width)
        self.height = int(height)
        for name, v in (("fx", fx), ("fy", fy), ("cx", cx), ("cy", cy)):
            try:
                fv = float(v)
            except Exception:
                raise ValueError(f"Camera {name}: expected a number, got {v!r}") from None
            if not np.isfinite(fv):
                raise ValueError(f"Camera {name}: must be finite, got {v!r}")
            if name in ("fx", "fy") and fv <= 0:
                raise ValueError(f"Camera {name}: focal length must be > 0, got {v!r}")
            setattr(self, name, fv)
        m = _finite_array("Camera world_to_camera", world_to_camera, np.float64, "[4, 4]", ndim=2)
        if m.shape != (4, 4):
            raise ValueError(f"Camera world_to_camera: expected shape [4, 4], got {m.shape}")
        self.world_to_camera = m.astype(np.float64).copy()

    @property
    def R(self):  # [3, 3]
        return self.world_to_camera[:3, :3]

    @property
    def t(self):  # [3]
        return self.world_to_camera[:3, 3]

    @property
    def center(self):  # [3] camera centre in world coordinates
        return -self.R.T @ self.t

    def project(self, points):
        """Pixel positions ``[N, 2]`` and camera-space depths ``[N]`` of world ``points [N, 3]``
        (float64). Points at z <= 0 get finite but meaningless pixels: mask them by depth."""
        x = np.asarray(points, np.float64) @ self.R.T + self.t
        z = x[:, 2]
        zs = np.where(z > 0, z, 1.0)
        return np.stack([self.fx * x[:, 0] / zs + self.cx, self.fy * x[:, 1] / zs + self.cy], axis=1), z

    def scaled(self, factor):
        """The same camera with the image scaled by ``factor`` (intrinsics follow)."""
        w = max(1, int(round(self.width * factor)))
        h = max(1, int(round(self.height * factor)))
        sx, sy = w / self.width, h / self.height
        return Camera(w, h, self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy, self.world_to_camera)

    def __repr__(self):
        return (f"Camera({self.width}x{self.height}, fx={self.fx:.6g}, fy={self.fy:.6g}, "
                f"cx={self.cx:.6g}, cy={self.cy:.6g})")


class TriangleModel:
    """Vertices and the triangles that share them.

    Args:
        positions: ``[N, 3]`` float vertex positions (world space).
        triangles: ``[M, 3]`` integer vertex indices, each in ``[0, N)``.
        sh: ``[N, K, 3]`` spherical-harmonics colour coefficients, K in {1, 4, 9, 16};
            colour = max(0, SH(dir) + 0.5) with dir the unit vector camera centre -> vertex.
        opacity: ``[N]`` activated opacity in [0, 1]; a triangle's opacity is the
            minimum of its three vertices'.
    """

    def __init__(self, positions, triangles, sh, opacity):
        pos = _finite_array("positions", positions, np.float64, "[N, 3]", ndim=2)
        if pos.shape[1] != 3:
            raise ValueError(f"positions: expected shape [N, 3], got {pos.shape}")
        n = pos.shape[0]
        tri = np.asarray(triangles)
        if tri.ndim != 2 or tri.shape[1] != 3:
            raise ValueError(f"triangles: expected shape [M, 3], got {tri.shape}")
        if tri.size and not np.issubdtype(tri.dtype, np.integer):
            if np.issubdtype(tri.dtype, np.floating) and np.all(np.isfinite(tri)) and np.all(tri == np.round(tri)):
                pass
            else:
                raise ValueError(f"triangles: expected integer vertex indices, got dtype {tri.dtype}")
        if tri.size:
            lo, hi = int(tri.min()), int(tri.max())
            if lo < 0 or hi >= n:
                raise ValueError(f"triangles: index out of range [0, {n}) (min {lo}, max {hi})")
        tri = tri.astype(np.int64)
        sh_arr = _finite_array("sh", sh, np.float64, "[N, K, 3]", ndim=3)
        if sh_arr.shape[0] != n or sh_arr.shape[2] != 3 or sh_arr.shape[1] not in SH_SIZES:
            raise ValueError(f"sh: expected shape [N={n}, K in {SH_SIZES}, 3], got {sh_arr.shape}")
        op = _finite_array("opacity", opacity, np.float64, "[N]", ndim=1)
        if op.shape[0] != n:
            raise ValueError(f"opacity: expected shape [N={n}], got {op.shape}")
        if op.size and (op.min() < 0.0 or op.max() > 1.0):
            raise ValueError(f"opacity: values must be activated opacities in [0, 1] "
                             f"(got min {op.min():.6g}, max {op.max():.6g})")
        self.positions = pos    # [N, 3]
        self.triangles = tri    # [M, 3]
        self.sh = sh_arr        # [N, K, 3]
        self.opacity = op       # [N]

    @property
    def num_vertices(self):
        return self.positions.shape[0]

    @property
    def num_triangles(self):
        return self.triangles.shape[0]

    @property
    def sh_size(self):
        return self.sh.shape[1]

    def __repr__(self):
        return f"TriangleModel(vertices={self.num_vertices}, triangles={self.num_triangles}, sh={self.sh_size})"


@dataclass
class Grads:
    v_positions: np.ndarray  # [N, 3]
    v_sh: np.ndarray         # [N, K, 3]
    v_opacity: np.ndarray    # [N]


def check_cotangents(v_image, v_transmittance, height, width):
    """Validate the incoming gradients: finite arrays of the image's shape."""
    vi = np.asarray(v_image, dtype=np.float64)
    if vi.shape != (height, width, 3):
        raise ValueError(f"v_image: expected shape [{height}, {width}, 3], got {vi.shape}")
    if not np.all(np.isfinite(vi)):
        raise ValueError("v_image: contains NaN or Inf")
    if v_transmittance is None:
        vt = np.zeros((height, width))
    else:
        vt = np.asarray(v_transmittance, dtype=np.float64)
        if vt.shape != (height, width):
            raise ValueError(f"v_transmittance: expected shape [{height}, {width}], got {vt.shape}")
        if not np.all(np.isfinite(vt)):
            raise ValueError("v_transmittance: contains NaN or Inf")
    return vi, vt


SH_C0 = 0.28209479177387814


def check_render_args(sigma, background, near):
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
