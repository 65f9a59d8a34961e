"""Host image metrics (NumPy, float64): PSNR and SSIM (3DGS's 11 x 11 Gaussian window,
sigma 1.5, zero-padded 'same' blur), the numbers every command and report prints."""

from __future__ import annotations

import math

import numpy as np

WINDOW = 11
WINDOW_SIGMA = 1.5
C1 = 0.01 ** 2
C2 = 0.03 ** 2


def psnr(a, b):
    """Peak signal-to-noise ratio in dB of two images in [0, 1] (inf when equal)."""
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return float("inf") if mse == 0 else -10.0 * math.log10(mse)


def gaussian_window(size=WINDOW, sigma=WINDOW_SIGMA):
    """The normalised 1-D Gaussian of 3DGS's ``create_window`` (float64)."""
    x = np.arange(size, dtype=np.float64) - size // 2
    g = np.exp(-x * x / (2.0 * sigma * sigma))
    return g / g.sum()


def blur_axis(a, g, axis):
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
    return blur_axis(blur_axis(np.asarray(a, np.float64), g, 1), g, 0)


def ssim_map(image, target):
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


def ssim(a, b):
    """Mean SSIM of two images [H, W, C] in [0, 1]."""
    return float(ssim_map(a, b).mean())
