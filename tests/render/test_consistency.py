"""Issue 6, point 4: at the end of training, the depth-tested mesh renderer (what an engine
draws) and the trainer's own renderer agree on held-out views of the procedural scene.

Topology is off: 150 quick iterations on the tiny scene are too short for pruning to pay off
(with it on the mesh ends below the initial model, 18.85 vs 20.99 dB, as a few hundred
scattered triangles whose centroid order and per-pixel depth order differ more: 18.64 vs
18.44 dB on the one held-out view), and this test is about the two renderers, not topology."""

import json

from tsplus_wgpu.cli.main import main


def test_mesh_and_trainer_renderer_agree_after_training(tmp_path):
    run = tmp_path / "run"
    assert main(["train", "procedural:tiny", "--out", str(run), "--preset", "quick", "--iterations", "150",
                 "--seed", "0", "--topology", "off", "--no-progress"]) == 0
    assert main(["eval", str(run), "procedural:tiny", "--out", str(tmp_path / "eval"), "--write-images", "0"]) == 0
    rep = json.loads((tmp_path / "eval" / "metrics.json").read_text())
    mesh, splat = rep["mean_psnr"], rep["mean_splat_psnr"]
    assert mesh > 15.0 and splat > 15.0          # a real reconstruction, not two blank images
    # the trainer composites triangles in centroid-depth order, the mesh renderer depth-tests per
    # pixel: where the two orders differ the images differ. Issue 16 asks for the exported mesh
    # within 0.5 dB of the trainer's render; with the background shell (large, far triangles)
    # this run measures 0.34 dB (mesh 19.91, splat 19.58 at the shell's introduction), 0.2 before.
    assert abs(mesh - splat) <= 0.5, (mesh, splat)
