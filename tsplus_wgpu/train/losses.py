"""The photometric loss ``0.8 * L1 + 0.2 * (1 - SSIM)`` and its gradient with respect to the
rendered image, on the device (WGSL; the constants live in ``shaders/common/ssim.wgsl``).
Float64 twin: :func:`tsplus_wgpu.reference.loss.image_loss`.

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

from ..gpu import GpuContext, Scratch
from ..kernels.loss import SsimBlurH, SsimGradH, SsimGradV, SsimLoss, SsimReduce


class ImageLoss:
    """``0.8 * L1 + 0.2 * (1 - SSIM)`` and d loss / d image on the device (5 dispatches).

    Scratch memory: 112 bytes per pixel (the row-blur buffer of 64 B/pixel is the largest
    single binding, so images up to about 2.09 Mpx fit the 128 MiB WebGPU default limit).

    Args:
        ctx: the :class:`~tsplus_wgpu.gpu.GpuContext`.
        scratch: a :class:`~tsplus_wgpu.gpu.Scratch` to share buffers with (optional).
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
        partials = self.scratch.get("ssim_partials", 8 * self.loss.partial_count(width, height))
        self.blur_h(enc, sp, image, target, rows, width, height, profiler)
        self.loss(enc, sp, image, target, rows, dmaps, partials, width, height, profiler)
        self.reduce(enc, sp, partials, result, profiler)
        self.grad_h(enc, sp, dmaps, rows, width, height, profiler)       # rows is free again: reuse it
        self.grad_v(enc, sp, image, target, rows, v_image, width, height, profiler)

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
