"""The trainer's small per-vertex / per-pixel kernels and their float64 twins.

* ``train_activate`` (:class:`TrainActivate`): trained parameters -> the renderer's inputs:
  opacity ``o = m + (1 - m) sigmoid(w)`` (re-inverting ``w`` first when the floor moves) and
  SH from the planar ``[K, N, 3]`` layout (SH DC and SH rest are contiguous ranges there, the
  Adam groups) to the renderer's ``[N, K, 3]``. Twin: :func:`activate_reference`.
* ``train_grads`` (:class:`TrainGrads`): renderer gradients -> parameter gradients:
  ``v_w = (v_o + reg) (1 - m) s (1 - s)`` and ``v_sh`` to planar with the bands above the
  scheduled SH degree zeroed. Twin: :func:`grads_reference`.
* ``pack_v_out`` (:class:`PackVOut`): ``[H, W, 3]`` dL/d image -> the backward's ``[H * W]``
  vec4 input. Twin: :func:`pack_v_out_reference`.
* ``opacity_reg`` (:class:`OpacityReg`): the early opacity loss ``weight * mean_T o_T``,
  per corner, then summed per vertex with :class:`~tsplus_wgpu.backward.SegmentSum` over the
  corners sorted by vertex (sorted once per topology on the host). Twin:
  :func:`opacity_reg_reference`.
* ``downsample_area`` (:class:`DownsampleArea`) and its transpose ``downsample_area_t``
  (:class:`DownsampleAreaT`): anti-aliasing by supersampling (method.md): the image rendered
  with the exact s-times camera (:func:`supersampled_camera`) is area-averaged over s x s
  blocks; the loss gradient goes back through the transpose (each sub-pixel gets its pixel's
  gradient / s^2, in the backward's vec4 layout). Twins: :func:`downsample_area_reference`,
  :func:`downsample_area_t_reference`.
"""

from __future__ import annotations

import numpy as np

from ..backward import SegmentSum
from ..gpu import Stage, grid
from .schedules import sigmoid

REINVERT_EPS = 1e-6


def _groups(n):
    return max(1, (int(n) + 255) // 256)


# ---------------------------------------------------------------------- twins

def activate_reference(sh_planar, logits, floor, floor_old=None, eps=REINVERT_EPS):
    """Returns ``(sh [N, K, 3], opacity [N], logits [N])`` in float64 (logits re-inverted
    when ``floor_old`` is given)."""
    sp = np.asarray(sh_planar, np.float64)
    w = np.asarray(logits, np.float64)
    if floor_old is not None:
        o_old = floor_old + (1.0 - floor_old) * sigmoid(w)
        q = np.clip((o_old - floor) / (1.0 - floor), eps, 1.0 - eps)
        w = np.log(q) - np.log1p(-q)
    return sp.transpose(1, 0, 2).copy(), floor + (1.0 - floor) * sigmoid(w), w


def grads_reference(logits, v_sh, v_opacity, floor, active_k, reg=None):
    """Returns ``(v_sh_planar [K, N, 3], v_logits [N])`` in float64."""
    w = np.asarray(logits, np.float64)
    s = sigmoid(w)
    vo = np.asarray(v_opacity, np.float64) + (0.0 if reg is None else np.asarray(reg, np.float64))
    vsp = np.asarray(v_sh, np.float64).transpose(1, 0, 2).copy()
    vsp[int(active_k):] = 0.0
    return vsp, vo * (1.0 - floor) * s * (1.0 - s)


def pack_v_out_reference(v_image):
    vi = np.asarray(v_image, np.float64).reshape(-1, 3)
    return np.concatenate([vi, np.zeros((len(vi), 1))], axis=1)


def opacity_reg_reference(triangles, opacity, weight, num_vertices):
    """d (weight * mean over triangles of min corner opacity) / d opacity, ``[N]`` float64
    (ties to the lowest vertex index)."""
    tri = np.asarray(triangles, np.int64)
    op = np.asarray(opacity, np.float64)
    out = np.zeros(int(num_vertices))
    if len(tri) == 0:
        return out
    o = op[tri]
    om = o.min(axis=1, keepdims=True)
    cand = np.where(o == om, tri, np.iinfo(np.int64).max)
    np.add.at(out, cand.min(axis=1), weight / len(tri))
    return out


def supersampled_camera(camera, s):
    """The exact s-times camera: ``fx s, fy s, cx s, cy s, width s, height s``. With pixel
    centres at ``(j + 0.5, i + 0.5)`` the s x s sub-pixels of pixel (i, j) have centres at
    ``j + (b + 0.5) / s`` (b = 0..s-1), mean ``j + 0.5``: their area average is that pixel."""
    from ..types import Camera
    s = int(s)
    if s < 1:
        raise ValueError(f"supersampling factor: expected an integer >= 1, got {s}")
    if s == 1:
        return camera
    return Camera(camera.width * s, camera.height * s, camera.fx * s, camera.fy * s, camera.cx * s, camera.cy * s,
                  camera.world_to_camera)


def downsample_area_reference(image, s):
    """``[s H, s W, C]`` -> ``[H, W, C]``: the mean of each s x s block (float64)."""
    img = np.asarray(image, np.float64)
    h, w = img.shape[0] // s, img.shape[1] // s
    return img.reshape(h, s, w, s, -1).mean(axis=(1, 3))


def downsample_area_t_reference(v_image, s):
    """The transpose of :func:`downsample_area_reference`: ``[H, W, C]`` -> ``[s H, s W, C]``,
    every sub-pixel the value of its pixel / s^2 (float64)."""
    v = np.asarray(v_image, np.float64) / (s * s)
    return np.repeat(np.repeat(v, s, axis=0), s, axis=1)


# ---------------------------------------------------------------------- device

class TrainActivate(Stage):
    stage = "train_activate"

    def __call__(self, enc, sh_planar, logits, sh, opacity, n, k, floor, floor_old=None, eps=REINVERT_EPS,
                 profiler=None):
        ap = self.uniform("ActivateParams", n=n, k=k, reinvert=int(floor_old is not None), floor=floor,
                          floor_old=0.0 if floor_old is None else floor_old, eps=eps)
        self.dispatch(enc, _groups(n), dict(ap=ap, sh_planar=sh_planar, logits=logits, sh=sh, opacity=opacity),
                      profiler)


class TrainGrads(Stage):
    stage = "train_grads"

    def __call__(self, enc, logits, v_sh, v_opacity, reg, v_sh_planar, v_logits, n, k, active_k, floor,
                 use_reg, profiler=None):
        gp = self.uniform("GradParams", n=n, k=k, active_k=active_k, use_reg=int(bool(use_reg)), floor=floor)
        self.dispatch(enc, _groups(n), dict(gp=gp, logits=logits, v_sh=v_sh, v_opacity=v_opacity, reg=reg,
                                            v_sh_planar=v_sh_planar, v_logits=v_logits), profiler)


class PackVOut(Stage):
    stage = "pack_v_out"

    def __call__(self, enc, v_image, v_out, num_pixels, profiler=None):
        pp = self.uniform("PackParams", num_pixels=num_pixels)
        self.dispatch(enc, _groups(num_pixels), dict(pp=pp, v_image=v_image, v_out=v_out), profiler)


class DownsampleArea(Stage):
    """``fine [s H * s W * 3]`` -> ``coarse [H * W * 3]`` (area mean), ``width``/``height`` coarse."""
    stage = "downsample_area"

    def __call__(self, enc, fine, coarse, width, height, s, profiler=None):
        dp = self.uniform("DownParams", width=width, height=height, factor=s, inv_area=1.0 / (s * s))
        self.dispatch(enc, _groups(width * height), dict(dp=dp, fine=fine, coarse=coarse), profiler)


class DownsampleAreaT(Stage):
    """``v_coarse [H * W * 3]`` -> ``v_fine [s H * s W]`` vec4 (the backward's input, ``.w = 0``)."""
    stage = "downsample_area_t"

    def __call__(self, enc, v_coarse, v_fine, width, height, s, profiler=None):
        dp = self.uniform("DownParams", width=width, height=height, factor=s, inv_area=1.0 / (s * s))
        self.dispatch(enc, _groups(width * height * s * s), dict(dp=dp, v_coarse=v_coarse, v_fine=v_fine),
                      profiler)


class OpacityReg:
    """The early opacity loss's gradient per vertex, on the device, deterministic.

    ``set_topology`` (host, once per triangle list) sorts the corners by vertex; ``record``
    writes per-corner values (``opacity_reg.wgsl``) and sums them per vertex into ``out``
    (``[N]`` vec4, the gradient in ``.x``)."""

    stage = "opacity_reg"

    def __init__(self, ctx, scratch):
        self.ctx = ctx
        self.kernel = _OpacityRegStage(ctx)
        self.sum = SegmentSum(ctx, scratch, "opacity_reg_sum")
        self.keys = self.index = None
        self.m = 0

    def set_topology(self, triangles):
        tri = np.asarray(triangles, np.int64).reshape(-1)
        order = np.argsort(tri, kind="stable").astype(np.uint32)   # corners by vertex, in corner order
        self.keys = self.ctx.upload(tri[order].astype(np.uint32), "opacity_reg_keys")
        self.index = self.ctx.upload(order, "opacity_reg_index")
        self.m = len(tri) // 3

    def record(self, enc, triangles, opacity, corner_vals, out, weight, profiler=None):
        rp = self.kernel.uniform("RegParams", num_triangles=self.m, per_triangle=float(weight) / max(self.m, 1))
        self.kernel.dispatch(enc, _groups(self.m), dict(rp=rp, triangles=triangles, opacity=opacity,
                                                        corner_vals=corner_vals), profiler)
        self.sum.record(enc, self.keys, self.index, corner_vals, 3 * self.m, 1, out, profiler, "opacity_reg")


class _OpacityRegStage(Stage):
    stage = "opacity_reg"


__all__ = ["TrainActivate", "TrainGrads", "PackVOut", "OpacityReg", "DownsampleArea", "DownsampleAreaT",
           "supersampled_camera", "downsample_area_reference", "downsample_area_t_reference", "activate_reference", "grads_reference",
           "pack_v_out_reference", "opacity_reg_reference", "grid"]
