"""Adam on the device (``shaders/adam.wgsl``), one dispatch per parameter group, and its
float64 twin. Defaults from method.md: beta1 0.9, beta2 0.999, eps 1e-15.

The update is PyTorch's (``torch.optim.Adam``, no weight decay, no amsgrad):
``p -= lr * (m / (1 - b1^t)) / (sqrt(v / (1 - b2^t)) + eps)`` with t the 1-based step.
"""

from __future__ import annotations

import numpy as np

from ..gpu import GpuContext, Stage, grid
from .schedules import ADAM_EPS

BETA1 = 0.9
BETA2 = 0.999


def _bias(beta, step):
    return 1.0 - beta ** int(step)


def adam_reference(param, grad, m, v, lr, step, beta1=BETA1, beta2=BETA2, eps=ADAM_EPS):
    """One Adam step in float64. Returns new ``(param, m, v)``; ``step`` is 1-based."""
    if int(step) < 1:
        raise ValueError(f"step: expected >= 1 (1-based), got {step!r}")
    p, g = np.asarray(param, np.float64), np.asarray(grad, np.float64)
    m = beta1 * np.asarray(m, np.float64) + (1.0 - beta1) * g
    v = beta2 * np.asarray(v, np.float64) + (1.0 - beta2) * g * g
    p = p - lr * (m / _bias(beta1, step)) / (np.sqrt(v / _bias(beta2, step)) + eps)
    return p, m, v


class Adam(Stage):
    """Records Adam steps on flat f32 buffers (param, grad, exp_avg, exp_avg_sq).

    A parameter group is a range ``[offset, offset + n)`` of the buffers (elements), so groups
    with different learning rates may share a buffer (e.g. SH DC and SH rest).
    """

    stage = "adam"

    def __init__(self, ctx: GpuContext, beta1=BETA1, beta2=BETA2, eps=ADAM_EPS):
        super().__init__(ctx)
        self.beta1, self.beta2, self.eps = float(beta1), float(beta2), float(eps)

    def record(self, enc, param, grad, exp_avg, exp_avg_sq, n, lr, step, offset=0, profiler=None, max_dim=None):
        """One step of one group. ``step`` is the group's 1-based step count (bias correction).
        ``max_dim`` overrides the per-dimension workgroup limit (tests of the 2-D grid)."""
        n, offset = int(n), int(offset)
        if n < 0 or offset < 0:
            raise ValueError(f"Adam: n and offset must be >= 0, got n={n}, offset={offset}")
        if int(step) < 1:
            raise ValueError(f"Adam: step is 1-based, got {step!r}")
        for name, buf in (("param", param), ("grad", grad), ("exp_avg", exp_avg), ("exp_avg_sq", exp_avg_sq)):
            if buf.size < 4 * (offset + n):
                raise ValueError(f"Adam: buffer {name} holds {buf.size // 4} floats, needs {offset + n}")
        if n == 0:
            return
        ap = self.uniform("AdamParams", offset=offset, n=n, lr=lr, beta1=self.beta1, beta2=self.beta2,
                          one_minus_beta1=1.0 - self.beta1, one_minus_beta2=1.0 - self.beta2,
                          eps=self.eps, bias1=_bias(self.beta1, step), bias2=_bias(self.beta2, step))
        groups = (n + 255) // 256
        dims = grid(groups, max_dim or self.ctx.limits["max-compute-workgroups-per-dimension"])
        self.dispatch(enc, dims, dict(ap=ap, param=param, grad=grad, exp_avg=exp_avg, exp_avg_sq=exp_avg_sq),
                      profiler)
