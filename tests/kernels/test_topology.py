"""shaders/topology/: max_weight_accumulate against its twin (tsplus_wgpu.reference.topology)."""

import numpy as np

from tsplus_wgpu.kernels.topology import MaxWeightAccumulate
from tsplus_wgpu.reference.topology import max_weight_accumulate


def test_max_weight_accumulate(ctx):
    k = MaxWeightAccumulate(ctx)
    rng = np.random.default_rng(0)
    for m in (1, 300, 70000):
        a0 = rng.random(m).astype(np.float32)
        w = rng.random(m).astype(np.float32)
        acc = ctx.upload(a0)
        wb = ctx.upload(w)
        for reset in (False, True):
            ctx.queue.write_buffer(acc, 0, a0.tobytes())
            enc = ctx.device.create_command_encoder()
            k(enc, wb, acc, m, reset=reset)
            ctx.queue.submit([enc.finish()])
            np.testing.assert_array_equal(ctx.read(acc, np.float32, m), max_weight_accumulate(a0, w, reset))
