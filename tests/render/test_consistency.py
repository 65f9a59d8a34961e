"""Issue 6, point 4: at the end of training, the depth-tested mesh renderer (what an engine
draws) and the trainer's own renderer agree on held-out views of the procedural scene.

Topology is off: 150 quick iterations on the tiny scene are too short for pruning to pay off
(with it on the mesh ends below the initial model, 18.85 vs 20.99 dB, as a few hundred
scattered triangles whose centroid order and per-pixel depth order differ more: 18.64 vs
18.44 dB on the one held-out view), and this test is about the two renderers, not topology.
The colour detail is off too: a fit after training, not either renderer, whose splits add
seams that the splat renderer lets a little background through (llvmpipe: 0.95 dB apart with
it, 0.89 without)."""

import json

from tsplus_wgpu.cli.main import main


def _train_eval(tmp_path, name, *extra):
    run = tmp_path / name
    assert main(["train", "procedural:tiny", "--out", str(run), "--preset", "quick", "--iterations", "150",
                 "--seed", "0", "--topology", "off", "--color-detail", "off", "--no-progress", *extra]) == 0
    assert main(["eval", str(run), "procedural:tiny", "--out", str(tmp_path / f"eval-{name}"),
                 "--write-images", "0"]) == 0
    rep = json.loads((tmp_path / f"eval-{name}" / "metrics.json").read_text())
    return rep["mean_psnr"], rep["mean_splat_psnr"]


def test_mesh_and_trainer_renderer_agree_after_training(tmp_path):
    # the paper's cleanup (--final-prune on): one visible layer left
    mesh, splat = _train_eval(tmp_path, "pruned", "--final-prune", "on")
    assert mesh > 15.0 and splat > 15.0          # a real reconstruction, not two blank images
    # the trainer composites triangles in centroid-depth order, the mesh renderer depth-tests per
    # pixel: where the two orders differ the images differ, and the depth test is right. Measured:
    # 0.2 dB before the background shell, 0.34 with it (mesh 19.91, splat 19.58), 0.50 with carving
    # (20.81 / 20.31), 0.61 with the shell's backdrop beyond the training views kept (21.69 / 21.09:
    # large far triangles, where centroid order errs most). 2026-11-27, llvmpipe: 0.89 (22.87 /
    # 21.98; 0.95 with the colour detail, 22.23 / 21.28); an NVIDIA H100 with the detail: 1.30
    # (22.12 / 20.82: its float32 order, another 150-step trajectory). A dropped term in either
    # renderer costs several dB; the engine's view is never the worse one.
    assert -0.1 <= mesh - splat <= 1.5, (mesh, splat)
    # the default keeps the triangles hidden in every training view: more layers, so centroid order
    # composites some hidden ones in front (splat 23.14 dB) where the depth test does not (mesh
    # 23.80 dB, measured at its introduction). Which of the two runs ends higher is the luck of a
    # 150-step trajectory: in the GPU kernel layout (sums in another order) kept gave 21.53 dB
    # against 22.87 pruned, on lavapipe's layout 23.8 against 22.23; a broken variant loses more
    kept_mesh, kept_splat = _train_eval(tmp_path, "kept")
    assert -0.1 <= kept_mesh - kept_splat <= 1.5, (kept_mesh, kept_splat)      # llvmpipe: 0.77
    assert kept_mesh >= mesh - 1.5, (kept_mesh, mesh, kept_splat, splat)
