"""shaders/bench/: peak_fma against its twin (tsplus_wgpu.reference.bench): what it writes."""

import numpy as np
import pytest

from tsplus_wgpu.kernels.bench import PeakFma
from tsplus_wgpu.reference.bench import FMA_ADD, FMA_MUL, SENTINEL, peak_fma, peak_fma_sums


@pytest.mark.parametrize("groups,iterations", [(1, 1), (3, 100)])
def test_peak_fma(ctx, groups, iterations):
    k = PeakFma(ctx)
    n = groups * k.invocations
    init = np.arange(4 * n, dtype=np.float32).reshape(n, 4) - 7.5      # not zero: an unexpected write shows
    sink = ctx.upload(init)
    enc = ctx.device.create_command_encoder()
    k(enc, sink, groups, iterations)
    ctx.queue.submit([enc.finish()])
    np.testing.assert_array_equal(ctx.read(sink, np.float32, 4 * n).reshape(n, 4), peak_fma(init, iterations))
    s = peak_fma_sums(n, iterations)
    assert np.all(np.isfinite(s)) and not np.any(s[:, 0] == SENTINEL)
    assert k.flop(groups, iterations) == n * iterations * 8 * 4 * 2
    # the twin's closed form against the kernel's loop, in float64
    seed = 1e-7 * np.arange(n, dtype=np.float64)[:, None] + np.array([0.0, 0.1, 0.2, 0.3])
    chains = [seed + 0.01 * c for c in range(8)]
    for _ in range(iterations):
        chains = [a * FMA_MUL + FMA_ADD for a in chains]
    np.testing.assert_allclose(s, sum(chains), rtol=1e-12)
