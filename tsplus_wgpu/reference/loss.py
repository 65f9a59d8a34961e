"""Float64 twins of shaders/loss/, one function per kernel (same name, same layouts), and of
the whole image loss (:func:`image_loss`, the twin of :class:`~tsplus_wgpu.train.losses.ImageLoss`).

The constants are read from ``shaders/common/ssim.wgsl``: the loss is
``L1_WEIGHT * L1 + SSIM_WEIGHT * (1 - SSIM)``, SSIM with C1, C2 and the 11-tap Gaussian window
(2 RADIUS + 1 taps, sigma WINDOW_SIGMA) as a 'same' zero-padded separable blur B: the window and
the blur are the SSIM metric's (:mod:`tsplus_wgpu.io.metrics`, one implementation)."""

from __future__ import annotations

import numpy as np

from ..gpu.wgsl import constant
from ..io.metrics import blur, blur_axis, gaussian_window, ssim_map  # noqa: F401  (one SSIM: the metric's)

C1 = constant("C1", "ssim")
C2 = constant("C2", "ssim")
L1_WEIGHT = constant("L1_WEIGHT", "ssim")
SSIM_WEIGHT = constant("SSIM_WEIGHT", "ssim")
WINDOW = 2 * constant("RADIUS", "ssim") + 1
WINDOW_SIGMA = constant("WINDOW_SIGMA", "ssim")
#: pixels per workgroup of ssim_loss (one partial per group)
SSIM_GROUP = constant("SSIM_GROUP", "ssim")
SSIM_SEG = constant("SSIM_SEG", "ssim")


def _row_blur(a):
    """The row ('same', zero-padded) Gaussian blur of ``a`` [H, W, ...] (axis 1)."""
    return blur_axis(np.asarray(a, np.float64), gaussian_window(), 1)


def _column_blur(a):
    """The column blur of ``a`` [H, W, ...] (axis 0)."""
    return blur_axis(np.asarray(a, np.float64), gaussian_window(), 0)


def _ssim_terms(mx, my, exx, eyy, exy):
    """The SSIM map m and its partials a = dm/dmu_x, b = dm/dE_xx, c = dm/dE_xy."""
    a1 = 2 * mx * my + C1
    a2 = 2 * (exy - mx * my) + C2
    d1 = mx * mx + my * my + C1
    d2 = (exx - mx * mx) + (eyy - my * my) + C2
    den = d1 * d2
    m = a1 * a2 / den
    a = 2 * my * (a2 - a1) / den - 2 * mx * m * (1.0 / d1 - 1.0 / d2)
    return m, a, -m / d2, 2 * a1 / den


def ssim_blur_h(image, target):
    """``rows [H, W, 4, 4]``: the row blur of x, y, x^2, y^2, xy (3 channels each) packed as the
    kernel's 4 vec4 per pixel: (x.rgb, y.r), (y.gb, xx.rg), (xx.b, yy.rgb), (xy.rgb, 0)."""
    x = np.asarray(image, np.float64)
    y = np.asarray(target, np.float64)
    h, w = x.shape[:2]
    packed = np.concatenate([x, y, x * x, y * y, x * y, np.zeros((h, w, 1))], axis=2)
    return _row_blur(packed).reshape(h, w, 4, 4)


def ssim_loss(image, target, rows):
    """``(dmaps [H, W, 3, 4], partials [G, 2])``: the column blur of ``rows`` gives the moments;
    dmaps holds (a.rgb, 0), (b.rgb, 0), (c.rgb, 0) per pixel; partials the sums of |x - y| and
    of m over the pixels of each workgroup: the kernel's invocation ``r W + col`` covers rows
    ``r SSIM_SEG`` to ``r SSIM_SEG + SSIM_SEG - 1`` of column ``col``, a workgroup
    ``SSIM_GROUP`` consecutive invocations (G = ceil(W ceil(H / SSIM_SEG) / SSIM_GROUP))."""
    x = np.asarray(image, np.float64)
    y = np.asarray(target, np.float64)
    h, w = x.shape[:2]
    s = _column_blur(np.asarray(rows, np.float64).reshape(h, w, 16))
    m, a, b, c = _ssim_terms(s[..., 0:3], s[..., 3:6], s[..., 6:9], s[..., 9:12], s[..., 12:15])
    dmaps = np.zeros((h, w, 3, 4))
    dmaps[:, :, 0, :3], dmaps[:, :, 1, :3], dmaps[:, :, 2, :3] = a, b, c
    per_pixel = np.stack([np.abs(x - y).sum(axis=2), m.sum(axis=2)], axis=-1)      # [H, W, 2]
    runs = -(-h // SSIM_SEG)
    per_run = np.zeros((runs * SSIM_SEG, w, 2))
    per_run[:h] = per_pixel
    per_run = per_run.reshape(runs, SSIM_SEG, w, 2).sum(axis=1).reshape(-1, 2)     # invocation r W + col
    groups = -(-len(per_run) // SSIM_GROUP)
    padded = np.zeros((groups * SSIM_GROUP, 2))
    padded[:len(per_run)] = per_run
    return dmaps, padded.reshape(groups, SSIM_GROUP, 2).sum(axis=1)


def ssim_grad_h(dmaps):
    """``grows [H, W, 3, 4]``: the row blur of the derivative maps."""
    return _row_blur(dmaps)


def ssim_grad_v(image, target, grows):
    """``v_image [H, W, 3]`` = ``(L1_WEIGHT sign(x - y) - SSIM_WEIGHT (B a + 2 x B b + y B c)) / N``,
    N = 3 H W, with the column blur of ``grows``."""
    x = np.asarray(image, np.float64)
    y = np.asarray(target, np.float64)
    g = _column_blur(grows)
    v_ssim = g[:, :, 0, :3] + 2 * x * g[:, :, 1, :3] + y * g[:, :, 2, :3]
    return (L1_WEIGHT * np.sign(x - y) - SSIM_WEIGHT * v_ssim) / x.size


def ssim_reduce(partials, num_pixels):
    """``[4]`` = (loss, l1, ssim, 0) from ssim_loss's partials, means over N = 3 num_pixels."""
    s = np.asarray(partials, np.float64).sum(axis=0) / (3.0 * int(num_pixels))
    return np.array([L1_WEIGHT * s[0] + SSIM_WEIGHT * (1.0 - s[1]), s[0], s[1], 0.0])


def image_loss(image, target, grad=True):
    """Float64 twin of :class:`~tsplus_wgpu.train.losses.ImageLoss` (the five SSIM twins chained).

    Args:
        image: ``[H, W, 3]`` rendered image.
        target: ``[H, W, 3]`` ground truth.
        grad: also return the gradient.

    Returns:
        ``(loss, l1, ssim, v_image)``: the loss ``L1_WEIGHT l1 + SSIM_WEIGHT (1 - ssim)``, its two
        terms (means over pixels and channels) and d loss / d image ``[H, W, 3]`` (None without grad).
    """
    x = np.asarray(image, np.float64)
    y = np.asarray(target, np.float64)
    if x.shape != y.shape or x.ndim != 3:
        raise ValueError(f"image and target: expected the same shape [H, W, C], got {x.shape} and {y.shape}")
    dmaps, partials = ssim_loss(x, y, ssim_blur_h(x, y))
    loss, l1, ssim, _ = ssim_reduce(partials, x.shape[0] * x.shape[1])
    if not grad:
        return float(loss), float(l1), float(ssim), None
    return float(loss), float(l1), float(ssim), ssim_grad_v(x, y, ssim_grad_h(dmaps))


def pack_v_out(v_image):
    """``[H, W, 3]`` -> ``[H W, 4]`` (dL/d rgb, dL/d T = 0)."""
    vi = np.asarray(v_image, np.float64).reshape(-1, 3)
    return np.concatenate([vi, np.zeros((len(vi), 1))], axis=1)


def downsample_area(image, s):
    """``[s H, s W, C]`` -> ``[H, W, C]``: the mean of each s x s block (float64)."""
    img = np.asarray(image, np.float64)
    h, w = img.shape[0] // s, img.shape[1] // s
    return img.reshape(h, s, w, s, -1).mean(axis=(1, 3))


def downsample_area_t(v_image, s):
    """The transpose of :func:`downsample_area`: ``[H, W, C]`` -> ``[s H, s W, C]``, every
    sub-pixel the value of its pixel / s^2 (float64; the kernel writes it as vec4, ``.w = 0``)."""
    v = np.asarray(v_image, np.float64) / (s * s)
    return np.repeat(np.repeat(v, s, axis=0), s, axis=1)


__all__ = ["C1", "C2", "L1_WEIGHT", "SSIM_WEIGHT", "WINDOW", "WINDOW_SIGMA", "SSIM_GROUP", "SSIM_SEG", "gaussian_window",
           "blur", "ssim_map", "ssim_blur_h", "ssim_loss", "ssim_grad_h", "ssim_grad_v", "ssim_reduce",
           "image_loss", "pack_v_out", "downsample_area", "downsample_area_t"]
