"""Float64 twins of shaders/topology/."""

from __future__ import annotations

import numpy as np


def max_weight_accumulate(acc, weights, reset=False):
    """``weights`` (``reset``) or the element-wise ``max(acc, weights)``, ``[M]`` (exact in f32)."""
    w = np.asarray(weights, np.float32)
    return w.copy() if reset else np.maximum(np.asarray(acc, np.float32), w)


__all__ = ["max_weight_accumulate"]
