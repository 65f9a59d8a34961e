"""Float64 twins of shaders/optim/, one function per kernel (same name), and the early opacity loss's gradient per vertex (:func:`opacity_reg_gradient`:
``opacity_reg_count``, then ``opacity_reg_scale``)."""

from __future__ import annotations

import numpy as np

from ..gpu.wgsl import constant

BETA1 = constant("BETA1", "adam")
BETA2 = constant("BETA2", "adam")
ADAM_EPS = constant("ADAM_EPS", "adam")
REINVERT_EPS = constant("REINVERT_EPS", "train_activate")


def sigmoid(w):
    """The logistic function, float64, stable for large |w|."""
    w = np.asarray(w, np.float64)
    e = np.exp(-np.abs(w))
    return np.where(w >= 0, 1.0 / (1.0 + e), e / (1.0 + e))


def train_activate(logits, floor, floor_old=None, eps=REINVERT_EPS):
    """Returns ``(opacity [N], logits [N])`` in float64 (logits re-inverted when ``floor_old``
    is given)."""
    w = np.asarray(logits, np.float64)
    if floor_old is not None:
        o_old = floor_old + (1.0 - floor_old) * sigmoid(w)
        q = np.clip((o_old - floor) / (1.0 - floor), eps, 1.0 - eps)
        w = np.log(q) - np.log1p(-q)
    return floor + (1.0 - floor) * sigmoid(w), w


def train_grads(logits, v_sh, v_opacity, floor, active_k, reg=None):
    """Returns ``(v_sh [N, K, 3] with the bands from active_k on zeroed, v_logits [N])`` in
    float64."""
    w = np.asarray(logits, np.float64)
    s = sigmoid(w)
    vo = np.asarray(v_opacity, np.float64) + (0.0 if reg is None else np.asarray(reg, np.float64))
    vs = np.asarray(v_sh, np.float64).copy()
    vs[:, int(active_k):] = 0.0
    return vs, vo * (1.0 - floor) * s * (1.0 - s)


def min_corner(tri, op):
    """Per triangle, the corner (0..2) holding the minimum opacity, ties to the lowest vertex index."""
    o = op[tri]
    cand = np.where(o == o.min(axis=1, keepdims=True), tri, np.iinfo(np.int64).max)
    return np.argmin(cand, axis=1)


def opacity_reg_count(triangles, opacity, num_vertices):
    """``[N]`` int64: per vertex, the triangles whose minimum opacity it holds (ties to the lowest
    vertex index)."""
    tri = np.asarray(triangles, np.int64).reshape(-1, 3)
    held = tri[np.arange(len(tri)), min_corner(tri, np.asarray(opacity, np.float64))]
    return np.bincount(held, minlength=int(num_vertices))


def opacity_reg_scale(counts, per_triangle):
    """``[N, 4]`` float64: ``counts * per_triangle`` in ``.x``, 0 elsewhere."""
    c = np.asarray(counts, np.float64)
    out = np.zeros((len(c), 4))
    out[:, 0] = c * float(per_triangle)
    return out


def opacity_reg_gradient(triangles, opacity, weight, num_vertices):
    """d (weight * mean over triangles of min corner opacity) / d opacity, ``[N]`` float64
    (ties to the lowest vertex index): ``weight / M`` times :func:`opacity_reg_count`."""
    m = len(np.asarray(triangles).reshape(-1, 3))
    return opacity_reg_scale(opacity_reg_count(triangles, opacity, num_vertices), float(weight) / max(m, 1))[:, 0]


def _bias(beta, step):
    return 1.0 - beta ** int(step)


def depth_scale(positions, centres, reach=1.0):
    """``[N]`` float64: ``min(1, distance to the nearest of centres [C, 3] / reach)`` per vertex."""
    p = np.asarray(positions, np.float64).reshape(-1, 3)
    c = np.asarray(centres, np.float64).reshape(-1, 3)
    best = np.full(len(p), np.inf)
    for x in c:
        best = np.minimum(best, ((p - x) ** 2).sum(-1))
    return np.minimum(1.0, np.sqrt(best) / float(reach))


def adam(param, grad, m, v, lr, step, beta1=BETA1, beta2=BETA2, eps=ADAM_EPS, scale=None, stride=1):
    """One Adam step in float64. Returns new ``(param, m, v)``; ``step`` is 1-based. ``scale``:
    one factor per ``stride`` elements, times the learning rate (the kernel's scale)."""
    if int(step) < 1:
        raise ValueError(f"step: expected >= 1 (1-based), got {step!r}")
    p, g = np.asarray(param, np.float64), np.asarray(grad, np.float64)
    if scale is not None:
        lr = lr * np.repeat(np.asarray(scale, np.float64), int(stride))[:len(p)]
    m = beta1 * np.asarray(m, np.float64) + (1.0 - beta1) * g
    v = beta2 * np.asarray(v, np.float64) + (1.0 - beta2) * g * g
    p = p - lr * (m / _bias(beta1, step)) / (np.sqrt(v / _bias(beta2, step)) + eps)
    return p, m, v


__all__ = ["BETA1", "BETA2", "ADAM_EPS", "REINVERT_EPS", "sigmoid", "min_corner", "train_activate", "train_grads", "opacity_reg_count",
           "opacity_reg_scale", "opacity_reg_gradient", "depth_scale", "adam"]
