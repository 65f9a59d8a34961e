"""Training with every array that may outgrow one storage binding bound in pieces
(gpu/chunks.py, forced small): the SH and their moments in ranges of vertices, the projected
triangles, their statistics, corner gradients and the opacity loss's corners in pages. The
elementwise kernels give the same bits; the sums over pages of corners add in another order,
so training follows the one-binding run closely rather than bit for bit."""

import numpy as np

import tsplus_wgpu.gpu.chunks as chunks
from tsplus_wgpu.data.procedural import load_procedural
from tsplus_wgpu.train.trainer import TrainConfig, Trainer


def _train(renderer, steps):
    scene = load_procedural("tiny", num_points=120)
    t = Trainer(scene, TrainConfig(iterations=300, quick=True, log_every=0, topology=False, seed=0),
                renderer=renderer)
    for _ in range(steps - 1):
        t.step()
    return t, t.step(read_stats=True)


def test_training_in_pages_follows_one_binding(renderer, monkeypatch):
    """One step: the same parameters but for the last bit of a few logits (the corners' sums in
    another order). Twelve: Adam (eps 1e-15) turns a gradient that cancels to 0 in one order
    and not in the other into a step of a whole learning rate, so the runs drift apart a little:
    the loss within 1 %, the training view's PSNR within 0.1 dB."""
    runs = {}
    for chunk in (None, 2**14):
        monkeypatch.setattr(chunks, "CHUNK_BYTES", chunk)
        runs[chunk] = [_train(renderer, steps) for steps in (1, 12)]
    (w1, _), (w12, a) = runs[None]
    (p1, _), (p12, b) = runs[2**14]
    assert w1.m * 96 > 2 * 2**14 and w1.n * 12 * w1.k > 2 * 2**14         # pages of triangles and of SH
    s1, t1 = w1.state_arrays(), p1.state_arrays()
    np.testing.assert_array_equal(t1["positions"], s1["positions"])
    np.testing.assert_array_equal(t1["sh_planar"], s1["sh_planar"])
    np.testing.assert_allclose(t1["logits"], s1["logits"], rtol=0, atol=1e-6)
    assert p12.n == w12.n and p12.m == w12.m
    assert abs(a["loss"] - b["loss"]) <= 0.01 * a["loss"] and abs(a["psnr"] - b["psnr"]) < 0.1
    assert all(np.all(np.isfinite(v)) for v in p12.state_arrays().values() if v.dtype.kind == "f")
