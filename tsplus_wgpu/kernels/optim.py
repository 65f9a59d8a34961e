"""Host classes of shaders/optim/: the trainer's per-vertex kernels and Adam. Twins:
:mod:`tsplus_wgpu.reference.optim` (same names).

* ``train_activate`` (:class:`TrainActivate`): the opacity logits -> the renderer's opacity
  ``o = m + (1 - m) sigmoid(w)`` (re-inverting ``w`` first when the floor moves). The SH
  parameters are in the renderer's ``[N, K, 3]`` layout, read by the renderer as they are.
* ``train_grads`` (:class:`TrainGrads`): renderer gradients -> parameter gradients:
  ``v_w = (v_o + reg) (1 - m) s (1 - s)``, and the bands of ``v_sh`` above the scheduled SH
  degree zeroed in place (``v_sh`` is then the SH parameters' gradient).
* ``opacity_reg_count`` and ``opacity_reg_scale`` (:class:`OpacityRegGradient`): the early
  opacity loss ``weight * mean_T o_T``'s gradient per vertex, ``weight / M`` times the count of
  triangles whose minimum opacity the vertex holds (counted with integer atomics: any order
  gives the same count).
* ``depth_scale`` (:class:`DepthScale`): per vertex, ``min(1, d / reach)`` with ``d`` its
  distance to the nearest training camera: the scale of its position learning rate.
* ``adam`` (:class:`Adam`): one Adam step of one parameter group (two learning rates in one
  group where its elements alternate: the SH's DC and the rest, per vertex; a scale per item
  where given: the positions' step by depth).

The per-vertex and per-element kernels take arrays larger than one storage binding a range at a
time (:mod:`tsplus_wgpu.gpu.chunks`).
"""

from __future__ import annotations

import numpy as np

from ..gpu import Stage, grid
from ..gpu.chunks import Slice, binding_bytes
from ..gpu.context import GpuContext


class TrainActivate(Stage):
    stage = "train_activate"

    def __call__(self, enc, logits, opacity, n, floor, floor_old=None, eps=None, profiler=None):
        """``eps``: the clamp of the re-inverted q (default: the shader's ``REINVERT_EPS``)."""
        eps = self.const("REINVERT_EPS") if eps is None else eps
        ap = self.uniform("ActivateParams", n=n, reinvert=int(floor_old is not None), floor=floor,
                          floor_old=0.0 if floor_old is None else floor_old, eps=eps)
        self.dispatch(enc, self.groups(n), dict(ap=ap, logits=logits, opacity=opacity), profiler)


class TrainGrads(Stage):
    stage = "train_grads"

    def __call__(self, enc, logits, v_sh, v_opacity, reg, v_logits, n, k, active_k, floor, use_reg,
                 profiler=None):
        """``v_sh`` ``[N, K, 3]`` is zeroed in place above ``active_k``; in chunks of vertices
        where it is larger than one binding."""
        self.dispatch_ranges(
            enc, n, dict(logits=(logits, 4), v_sh=(v_sh, 12 * k), v_opacity=(v_opacity, 4), reg=(reg, 16),
                         v_logits=(v_logits, 4)), {},
            lambda s, c: dict(gp=self.uniform("GradParams", n=c, k=k, active_k=active_k, use_reg=int(bool(use_reg)),
                                              floor=floor)), profiler)


class OpacityRegCount(Stage):
    """Per triangle, one count for the vertex holding its minimum opacity: ``counts [N]`` u32,
    added to (zero it first)."""
    stage = "opacity_reg_count"

    def __call__(self, enc, triangles, opacity, counts, m, profiler=None):
        if m == 0:
            return
        self.dispatch(enc, self.groups(m), dict(cp=self.uniform("CountParams", num_triangles=int(m)),
                                                triangles=triangles, opacity=opacity, counts=counts), profiler)


class OpacityRegScale(Stage):
    """Per vertex, ``out [N]`` vec4 with ``counts[v] * per_triangle`` in ``.x``."""
    stage = "opacity_reg_scale"

    def __call__(self, enc, counts, out, n, per_triangle, profiler=None):
        """In ranges of vertices where ``out`` outgrows one binding."""
        self.dispatch_ranges(enc, n, dict(counts=(counts, 4), out=(out, 16)), {},
                             lambda s, c: dict(sp=self.uniform("ScaleParams", n=c, per_triangle=float(per_triangle))),
                             profiler)


class OpacityRegGradient:
    """The early opacity loss's gradient per vertex, on the device, deterministic:
    ``weight / M`` times the number of triangles whose minimum opacity the vertex holds
    (:class:`OpacityRegCount`, integer atomics, then :class:`OpacityRegScale`). ``record``
    writes it into ``out`` (``[N]`` vec4, the gradient in ``.x``)."""

    def __init__(self, ctx, scratch):
        self.scratch = scratch
        self.count = OpacityRegCount(ctx)
        self.scale = OpacityRegScale(ctx)

    def record(self, enc, triangles, opacity, out, weight, n, m, profiler=None):
        """``n`` vertices (``out`` holds at least that many), ``m`` triangles."""
        counts = self.scratch.get("opacity_reg_counts", 4 * n)
        enc.clear_buffer(counts, 0, 4 * n)
        self.count(enc, triangles, opacity, counts, m, profiler)
        self.scale(enc, counts, out, n, float(weight) / max(m, 1), profiler)


def _bias(beta, step):
    return 1.0 - beta ** int(step)


class DepthScale(Stage):
    """Per vertex, ``min(1, distance to the nearest of centres / reach)``: the positions' step
    by depth (the shader's comment). ``centres``: a buffer of ``[C]`` vec4 (xyz)."""
    stage = "depth_scale"

    def __call__(self, enc, positions, centres, scale, n, num_centres, reach=1.0, profiler=None):
        if n == 0:
            return
        sp = self.uniform("ScaleParams", n=int(n), num_centres=int(num_centres), reach=float(reach))
        self.dispatch(enc, self.groups(n), dict(sp=sp, positions=positions, centres=centres, scale=scale), profiler)

    def centres(self, points, label="depth_scale_centres"):
        """``points [C, 3]`` uploaded as the kernel's vec4 centres."""
        c = np.zeros((max(1, len(points)), 4), np.float32)
        c[:len(points), :3] = np.asarray(points, np.float64).reshape(-1, 3)
        return self.ctx.upload(c, label)


class Adam(Stage):
    """Records Adam steps on flat f32 buffers (param, grad, exp_avg, exp_avg_sq).

    A parameter group is a range ``[offset, offset + n)`` of the buffers (elements), so groups
    with different learning rates may share a buffer (e.g. SH DC and SH rest). ``beta1``,
    ``beta2``, ``eps`` default to the shader's ``BETA1``, ``BETA2``, ``ADAM_EPS``.
    """

    stage = "adam"

    def __init__(self, ctx: GpuContext, beta1=None, beta2=None, eps=None):
        super().__init__(ctx)
        self.beta1 = float(self.const("BETA1") if beta1 is None else beta1)
        self.beta2 = float(self.const("BETA2") if beta2 is None else beta2)
        self.eps = float(self.const("ADAM_EPS") if eps is None else eps)
        self._no_scale = ctx.buffer(16, "adam_no_scale")     # bound, never read, without a scale

    def record(self, enc, param, grad, exp_avg, exp_avg_sq, n, lr, step, offset=0, profiler=None, max_dim=None,
               lr_tail=None, period=0, head=0, max_binding=None, scale=None, stride=1):
        """One step of one group. ``step`` is the group's 1-based step count (bias correction).
        ``max_dim`` overrides the per-dimension workgroup limit (tests of the 2-D grid).
        ``period``, ``head``, ``lr_tail``: element ``offset + k`` takes ``lr`` where ``k mod
        period < head``, else ``lr_tail`` (period 0: ``lr`` everywhere). ``scale``: a buffer of
        one f32 per ``stride`` elements of the group (e.g. per vertex of the positions, stride
        3): element ``offset + k``'s rate is also times ``scale[k // stride]``. Buffers larger
        than one binding (or than ``max_binding`` bytes: tests) are stepped a range at a time."""
        n, offset, period, stride = int(n), int(offset), int(period), int(stride)
        if n < 0 or offset < 0:
            raise ValueError(f"Adam: n and offset must be >= 0, got n={n}, offset={offset}")
        if int(step) < 1:
            raise ValueError(f"Adam: step is 1-based, got {step!r}")
        if stride < 1:
            raise ValueError(f"Adam: stride must be >= 1, got {stride}")
        for name, buf in (("param", param), ("grad", grad), ("exp_avg", exp_avg), ("exp_avg_sq", exp_avg_sq)):
            if buf.size < 4 * (offset + n):
                raise ValueError(f"Adam: buffer {name} holds {buf.size // 4} floats, needs {offset + n}")
        if scale is not None and scale.size < 4 * -(-n // stride):
            raise ValueError(f"Adam: buffer scale holds {scale.size // 4} floats, needs {-(-n // stride)}")
        if n == 0:
            return
        bufs = dict(param=param, grad=grad, exp_avg=exp_avg, exp_avg_sq=exp_avg_sq)
        const = dict(period=period, head=int(head), lr=lr, lr_tail=lr if lr_tail is None else lr_tail,
                     beta1=self.beta1, beta2=self.beta2, one_minus_beta1=1.0 - self.beta1,
                     one_minus_beta2=1.0 - self.beta2, eps=self.eps, bias1=_bias(self.beta1, step),
                     bias2=_bias(self.beta2, step), scale_stride=0 if scale is None else stride)
        max_dim = max_dim or self.ctx.limits["max-compute-workgroups-per-dimension"]
        cap = binding_bytes(self.ctx) if max_binding is None else int(max_binding)
        align = int(self.ctx.limits["min-storage-buffer-offset-alignment"])
        whole = max(b.size for b in bufs.values()) <= cap and (scale is None or scale.size <= cap)
        # ranges of at most cap - 256 bytes, each bound from the 256-byte boundary below it
        per = n if whole else (cap - align) // 4
        for start in range(offset, offset + n, per):
            count = min(per, offset + n - start)
            first = 0 if whole else 4 * start // align * align
            within = start - first // 4
            sbuf, sfields = self._scale_range(scale, start - offset, count, stride, whole, align)
            ap = self.uniform("AdamParams", offset=within, n=count, phase=(start - offset) % max(period, 1),
                              **const, **sfields)
            size = 4 * (within + count)
            bound = bufs if whole else {key: Slice(b, first, size) for key, b in bufs.items()}
            self.dispatch(enc, grid(self.groups(count), max_dim), dict(ap=ap, scale=sbuf, **bound), profiler)

    def _scale_range(self, scale, elem, count, stride, whole, align):
        """The scale's binding for the group's elements ``[elem, elem + count)`` and its uniform
        fields (the items from the 256-byte boundary below the first one's)."""
        if scale is None:
            return self._no_scale, dict(scale_elem=0, scale_first=0)
        if whole:
            return scale, dict(scale_elem=elem, scale_first=0)
        lo, hi = elem // stride, (elem + count - 1) // stride + 1
        first = 4 * lo // align * align
        return Slice(scale, first, 4 * hi - first), dict(scale_elem=elem, scale_first=first // 4)


__all__ = ["TrainActivate", "TrainGrads", "OpacityRegCount", "OpacityRegScale", "OpacityRegGradient", "DepthScale", "Adam"]
