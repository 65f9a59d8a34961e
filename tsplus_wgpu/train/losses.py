"""The photometric loss ``0.8 * L1 + 0.2 * (1 - SSIM)`` and its gradient with respect to the
rendered image, on the device (WGSL) and as a float64 NumPy twin.

SSIM as in 3DGS: per channel, 11x11 Gaussian window (sigma 1.5) applied as a 'same'
convolution with zero padding, C1 = 0.01^2, C2 = 0.03^2, mean over pixels and channels.
L1 is the mean absolute difference; its gradient at a tie (image == target) is 0.

With the blur B (symmetric, so B^T = B), mu_x = B x, E_xx = B x^2, E_xy = B xy and the
SSIM map m = A1 A2 / (D1 D2), A1 = 2 mu_x mu_y + C1, A2 = 2 (E_xy - mu_x mu_y) + C2,
D1 = mu_x^2 + mu_y^2 + C1, D2 = E_xx - mu_x^2 + E_yy - mu_y^2 + C2:

    d mean(m) / dx = (1/N) [ B a + 2 x (B b) + y (B c) ]
    a = dm/dmu_x = 2 mu_y (A2 - A1) / (D1 D2) - 2 mu_x m (1/D1 - 1/D2)
    b = dm/dE_xx = -m / D2
    c = dm/dE_xy = 2 A1 / (D1 D2)

The device path: ``ssim_blur_h`` (row blur of x, y, x^2, y^2, xy) -> ``ssim_loss`` (column
blur, SSIM map, a/b/c maps, per-workgroup loss partials) -> ``ssim_grad_h`` (row blur of
a, b, c) -> ``ssim_grad_v`` (column blur, v_image) and ``ssim_reduce`` (the loss from the
partials in a fixed order). No atomics: every output has one writer, every sum a fixed order.
"""

from __future__ import annotations

import numpy as np

WINDOW = 11
WINDOW_SIGMA = 1.5
C1 = 0.01 ** 2
C2 = 0.03 ** 2
L1_WEIGHT = 0.8
SSIM_WEIGHT = 0.2


def gaussian_window(size=WINDOW, sigma=WINDOW_SIGMA):
    """The normalised 1-D Gaussian of 3DGS's ``create_window`` (float64)."""
    x = np.arange(size, dtype=np.float64) - size // 2
    g = np.exp(-x * x / (2.0 * sigma * sigma))
    return g / g.sum()


def _blur_axis(a, g, axis):
    """'same' zero-padded correlation with the symmetric kernel g along one axis."""
    r = len(g) // 2
    n = a.shape[axis]
    out = np.zeros_like(a)
    for k, w in enumerate(g):
        d = k - r                         # out[i] += w * a[i + d]
        lo, hi = max(0, -d), min(n, n - d)
        if lo >= hi:
            continue
        src = [slice(None)] * a.ndim
        dst = [slice(None)] * a.ndim
        src[axis] = slice(lo + d, hi + d)
        dst[axis] = slice(lo, hi)
        out[tuple(dst)] += w * a[tuple(src)]
    return out


def blur(a, g=None):
    """Separable 'same' zero-padded 2-D Gaussian blur of ``a`` [H, W, ...] (float64)."""
    g = gaussian_window() if g is None else g
    return _blur_axis(_blur_axis(np.asarray(a, np.float64), g, 1), g, 0)


def ssim_map_reference(image, target):
    """Per-pixel, per-channel SSIM map [H, W, C] (float64)."""
    x = np.asarray(image, np.float64)
    y = np.asarray(target, np.float64)
    mx, my = blur(x), blur(y)
    exx, eyy, exy = blur(x * x), blur(y * y), blur(x * y)
    a1 = 2 * mx * my + C1
    a2 = 2 * (exy - mx * my) + C2
    d1 = mx * mx + my * my + C1
    d2 = (exx - mx * mx) + (eyy - my * my) + C2
    return a1 * a2 / (d1 * d2)


def image_loss_reference(image, target, grad=True):
    """Float64 twin of :class:`ImageLoss`.

    Args:
        image: ``[H, W, 3]`` rendered image.
        target: ``[H, W, 3]`` ground truth.
        grad: also return the gradient.

    Returns:
        ``(loss, l1, ssim, v_image)``: the loss ``0.8 l1 + 0.2 (1 - ssim)``, its two terms
        (means over pixels and channels) and d loss / d image ``[H, W, 3]`` (None without grad).
    """
    x = np.asarray(image, np.float64)
    y = np.asarray(target, np.float64)
    if x.shape != y.shape or x.ndim != 3:
        raise ValueError(f"image and target: expected the same shape [H, W, C], got {x.shape} and {y.shape}")
    n = x.size
    mx, my = blur(x), blur(y)
    exx, eyy, exy = blur(x * x), blur(y * y), blur(x * y)
    a1 = 2 * mx * my + C1
    a2 = 2 * (exy - mx * my) + C2
    d1 = mx * mx + my * my + C1
    d2 = (exx - mx * mx) + (eyy - my * my) + C2
    den = d1 * d2
    m = a1 * a2 / den
    l1 = float(np.abs(x - y).mean())
    ssim = float(m.mean())
    loss = L1_WEIGHT * l1 + SSIM_WEIGHT * (1.0 - ssim)
    if not grad:
        return loss, l1, ssim, None
    a = 2 * my * (a2 - a1) / den - 2 * mx * m * (1.0 / d1 - 1.0 / d2)
    b = -m / d2
    c = 2 * a1 / den
    v_ssim = (blur(a) + 2 * x * blur(b) + y * blur(c)) / n
    v_image = L1_WEIGHT * np.sign(x - y) / n - SSIM_WEIGHT * v_ssim
    return loss, l1, ssim, v_image


# ---------------------------------------------------------------------- device

from ..gpu import GpuContext, Stage  # noqa: E402
from ..stages import Scratch  # noqa: E402

_PER_GROUP = 256


def _groups(n):
    return max(1, (int(n) + _PER_GROUP - 1) // _PER_GROUP)


class _SsimStage(Stage):
    def params(self, width, height):
        n = int(width) * int(height)
        return self.uniform("SsimParams", width=width, height=height, num_pixels=n, inv_n=1.0 / (3.0 * n))


class SsimBlurH(_SsimStage):
    stage = "ssim_blur_h"

    def __call__(self, enc, sp, image, target, rows, num_pixels, profiler=None):
        self.dispatch(enc, _groups(num_pixels), dict(sp=sp, image=image, target_image=target, rows=rows), profiler)


class SsimLoss(_SsimStage):
    stage = "ssim_loss"

    def __call__(self, enc, sp, image, target, rows, dmaps, partials, num_pixels, profiler=None):
        self.dispatch(enc, _groups(num_pixels), dict(sp=sp, image=image, target_image=target, rows=rows,
                                                     dmaps=dmaps, partials=partials), profiler)


class SsimGradH(_SsimStage):
    stage = "ssim_grad_h"

    def __call__(self, enc, sp, dmaps, grows, num_pixels, profiler=None):
        self.dispatch(enc, _groups(num_pixels), dict(sp=sp, dmaps=dmaps, grows=grows), profiler)


class SsimGradV(_SsimStage):
    stage = "ssim_grad_v"

    def __call__(self, enc, sp, image, target, grows, v_image, num_pixels, profiler=None):
        self.dispatch(enc, _groups(num_pixels), dict(sp=sp, image=image, target_image=target, grows=grows,
                                                     v_image=v_image), profiler)


class SsimReduce(_SsimStage):
    stage = "ssim_reduce"

    def __call__(self, enc, sp, partials, result, profiler=None):
        self.dispatch(enc, 1, dict(sp=sp, partials=partials, result=result), profiler)


class ImageLoss:
    """``0.8 * L1 + 0.2 * (1 - SSIM)`` and d loss / d image on the device (5 dispatches).

    Scratch memory: 112 bytes per pixel (the row-blur buffer of 64 B/pixel is the largest
    single binding, so images up to about 2.09 Mpx fit the 128 MiB WebGPU default limit).

    Args:
        ctx: the :class:`~tsplus_wgpu.gpu.GpuContext`.
        scratch: a :class:`~tsplus_wgpu.stages.Scratch` to share buffers with (optional).
    """

    def __init__(self, ctx: GpuContext, scratch: Scratch | None = None):
        self.ctx = ctx
        self.scratch = scratch or Scratch(ctx)
        self.blur_h = SsimBlurH(ctx)
        self.loss = SsimLoss(ctx)
        self.grad_h = SsimGradH(ctx)
        self.grad_v = SsimGradV(ctx)
        self.reduce = SsimReduce(ctx)
        assert len({s.src.structs["SsimParams"] for s in (self.blur_h, self.loss, self.grad_h, self.grad_v,
                                                          self.reduce)}) == 1, "SsimParams differs between stages"

    def record(self, enc, image, target, v_image, result, width, height, profiler=None):
        """Record the loss and its gradient.

        Args:
            image, target: buffers of ``[H, W, 3]`` f32.
            v_image: output buffer ``[H, W, 3]`` f32, d loss / d image.
            result: output buffer of 4 f32: (loss, l1, ssim, 0).
        """
        n = int(width) * int(height)
        if n < 1:
            raise ValueError(f"image size must be at least 1x1, got {width}x{height}")
        sp = self.blur_h.params(width, height)
        rows = self.scratch.get("ssim_rows", 64 * n)
        dmaps = self.scratch.get("ssim_dmaps", 48 * n)
        partials = self.scratch.get("ssim_partials", 8 * _groups(n))
        self.blur_h(enc, sp, image, target, rows, n, profiler)
        self.loss(enc, sp, image, target, rows, dmaps, partials, n, profiler)
        self.reduce(enc, sp, partials, result, profiler)
        self.grad_h(enc, sp, dmaps, rows, n, profiler)       # rows is free again: reuse it
        self.grad_v(enc, sp, image, target, rows, v_image, n, profiler)

    def __call__(self, image, target):
        """Host convenience: arrays ``[H, W, 3]`` in, ``(loss, l1, ssim, v_image)`` out."""
        x = np.ascontiguousarray(image, np.float32)
        y = np.ascontiguousarray(target, np.float32)
        if x.shape != y.shape or x.ndim != 3 or x.shape[2] != 3:
            raise ValueError(f"image and target: expected the same shape [H, W, 3], got {x.shape} and {y.shape}")
        h, w = x.shape[:2]
        ctx = self.ctx
        bx, by = ctx.upload(x, "image"), ctx.upload(y, "target")
        v = ctx.buffer(4 * x.size, "v_image")
        res = ctx.buffer(16, "loss")
        enc = ctx.device.create_command_encoder()
        self.record(enc, bx, by, v, res, w, h)
        ctx.queue.submit([enc.finish()])
        r = ctx.read(res, np.float32, 4)
        return float(r[0]), float(r[1]), float(r[2]), ctx.read(v, np.float32, x.size).reshape(x.shape)
