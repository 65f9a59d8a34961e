"""Results do not depend on the world's units: the trainer works in the scene's normalised frame
(tsplus_wgpu/data/frame.py, docs/training.md#world-units). The tiny procedural scene and a copy
of it in millimetres far from the origin train to the same held-out PSNR and the same mesh (up to
the similarity between them), and checkpoints hold world-unit positions."""

import json

import numpy as np
import pytest
from scenes import similar_scene

from tsplus_wgpu.data import WorldFrame, load_procedural
from tsplus_wgpu.train.checkpoint import CheckpointError, read_checkpoint
from tsplus_wgpu.train.schedules import SIGMA_FINAL
from tsplus_wgpu.train.trainer import TrainConfig, Trainer

#: the copy's world: 1000x the scene's lengths, then this far from the origin
SCALE, SHIFT = 1000.0, (3.1e3, -2.7e3, 5.5e3)
#: quick-preset steps: 60 has three topology edits (iterations 22, 29, 50) and runs in ~12 s on lavapipe
STEPS = 60


@pytest.fixture(scope="module")
def runs(renderer, tmp_path_factory):
    """``{name: (trainer, scene, held-out PSNR of the soft model, of the exported mesh, mesh)}`` of
    the scene ("unit") and its copy ("far", trained with a checkpoint into ``out``)."""
    scene = load_procedural("tiny")
    copy, sim = similar_scene(scene, SCALE, SHIFT)
    cfg = TrainConfig(iterations=STEPS, quick=True, seed=0, log_every=0, background=scene.background)
    out = tmp_path_factory.mktemp("far")
    res = {}
    for name, sc, folder in (("unit", scene, None), ("far", copy, out)):
        t = Trainer(sc, cfg, renderer=renderer).train(out_dir=folder, progress=False)
        mesh = t.final_mesh()
        soft = t.evaluate()[0]
        hard = t.evaluate(Trainer.mesh_model(*mesh), sigma=SIGMA_FINAL)[0]
        res[name] = (t, sc, soft, hard, mesh)
    res["sim"], res["out"] = sim, out
    return res


def test_scaled_and_shifted_world_trains_to_the_same_result(runs):
    (a, _, soft_a, hard_a, mesh_a), (b, _, soft_b, hard_b, mesh_b) = runs["unit"], runs["far"]
    sim = runs["sim"]
    print(f"held-out PSNR: unit scene {soft_a:.3f} dB (mesh {hard_a:.3f}), x{SCALE:g} + {SHIFT} copy "
          f"{soft_b:.3f} dB (mesh {hard_b:.3f})")
    assert abs(soft_a - soft_b) < 0.1 and abs(hard_a - hard_b) < 0.1
    # the same frame, up to rounding: the frame cameras agree
    assert b.frame.scale == pytest.approx(a.frame.scale / SCALE, rel=1e-12)
    for ca, cb in zip(a.scene.cameras, b.scene.cameras):
        np.testing.assert_allclose(cb.world_to_camera, ca.world_to_camera, rtol=0, atol=1e-12)
    # the exported mesh of the copy is the scene's mapped by the similarity
    (pa, ta, ka), (pb, tb, kb) = mesh_a, mesh_b
    assert len(tb) > 0 and b.m == a.m and b.n == a.n
    np.testing.assert_array_equal(tb, ta)
    extent = 1.0 / b.frame.scale                      # the copy's camera radius, in its units
    np.testing.assert_allclose(pb, sim.to_frame(pa), rtol=0, atol=1e-4 * extent)
    np.testing.assert_allclose(kb, ka, rtol=0, atol=1e-3)


def test_checkpoint_holds_world_positions_and_resumes_exactly(runs, renderer):
    t, copy = runs["far"][:2]
    path = runs["out"] / "checkpoint.npz"
    with np.load(path) as z:
        pos = z["positions"]
        meta = json.loads(bytes(z["meta"]).decode())
    assert pos.dtype == np.float64 and meta["version"] == 2
    np.testing.assert_array_equal(pos, t.current_model().positions)          # world units, as mesh.ply
    assert WorldFrame.from_json(meta["frame"]) == t.frame
    unit = runs["unit"][0].current_model().positions                       # the copy's world, far out
    np.testing.assert_allclose(pos, runs["sim"].to_frame(unit), rtol=0, atol=1e-4 / t.frame.scale)
    # a resume maps them back with the stored frame: the device state comes back bit for bit
    resumed = Trainer.resume(path, copy, renderer=renderer)
    assert resumed.frame == t.frame and resumed.iteration == t.iteration
    a, b = t.state_arrays(), resumed.state_arrays()
    for k in a:
        np.testing.assert_array_equal(b[k], a[k], err_msg=k)


def test_version_1_checkpoint_is_refused_in_one_line(runs, tmp_path):
    with np.load(runs["out"] / "checkpoint.npz") as z:
        arrays = {k: z[k] for k in z.files}
    meta = json.loads(bytes(arrays["meta"]).decode())
    meta["version"] = 1
    del meta["frame"]
    arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    old = tmp_path / "checkpoint.npz"
    np.savez(old, **arrays)
    with pytest.raises(CheckpointError) as info:
        read_checkpoint(old)
    msg = str(info.value)
    assert "\n" not in msg and str(old) in msg and "older tsplus" in msg and "new --out" in msg, msg
    meta["version"] = 2                              # a version-2 checkpoint without its frame is corrupt
    arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    np.savez(old, **arrays)
    with pytest.raises(CheckpointError, match="frame"):
        read_checkpoint(old)
