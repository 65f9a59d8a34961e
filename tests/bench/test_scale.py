"""``tsplus bench-scale`` (tsplus_wgpu/bench/scale.py) on small sizes: the scene is what it says,
a size runs and matches the float64 twin on its crop, a size over the binding limit is a row
that names the buffer, and the command writes its JSON. No timing is asserted."""

import json
import re

import numpy as np
import pytest

from tsplus_wgpu import reference
from tsplus_wgpu.bench.scale import CROP, crop_twin, scale_report, scale_row, scale_scene


@pytest.mark.parametrize("n, degree", [(3_000, 3), (20_000, 1)])
def test_scale_scene_is_a_layered_surface_filling_the_view(n, degree):
    model, cam = scale_scene(n, 160, 90, sh_degree=degree)
    assert 0.9 * n <= model.num_vertices <= 1.02 * n
    assert 1.8 < len(model.triangles) / model.num_vertices < 2.0          # a surface: shared vertices
    assert np.unique(model.triangles).size == model.num_vertices
    assert model.sh.shape == (model.num_vertices, (degree + 1) ** 2, 3)
    for a in (model.positions, model.sh):
        np.testing.assert_array_equal(a, a.astype(np.float32))
    p = model.positions @ cam.R.T + cam.t
    assert p[:, 2].min() > 1.5
    u, v = cam.fx * p[:, 0] / p[:, 2] + cam.cx, cam.fy * p[:, 1] / p[:, 2] + cam.cy
    assert u.min() < 0 and u.max() > cam.width and v.min() < 0 and v.max() > cam.height   # past every edge


def test_crop_twin_is_the_twin_of_the_whole_image_on_the_crop():
    model, cam = scale_scene(1_500, 400, 48, sh_degree=1)
    whole = reference.render(model, cam, 0.5)
    part, drawn = crop_twin(reference.render, model, cam, 0.5, 300, 10, size=16)
    assert 0 < drawn < len(model.triangles)
    np.testing.assert_allclose(part.image, whole.image[10:26, 300:316], atol=1e-12)
    # the float32 error model at the kernel's pixel coordinates, not at a crop camera's smaller ones
    np.testing.assert_allclose(part.f32_bound, whole.f32_bound[10:26, 300:316], rtol=1e-12, atol=0)
    np.testing.assert_array_equal(part.ambiguous, whole.ambiguous[10:26, 300:316])


def test_a_size_runs_and_agrees_with_the_twin():
    from tsplus_wgpu import Renderer
    # a renderer of its own: the session's shares scratch buffers that earlier tests grew, which
    # this size then reuses, so its peak would depend on which tests ran before it in the worker
    row = scale_row(Renderer(), 4_000, 96, 64, sh_degree=3, reference_render=reference.render)
    assert "refused" not in row
    assert row["pairs"] > 0 and row["pairs_per_pixel"] == row["pairs"] / (96 * 64)
    assert row["forward_ms"] > 0 and row["backward_ms"] > 0
    sh_bytes = row["vertices"] * 16 * 12
    assert row["device_bytes_peak"] > 3 * sh_bytes                    # the SH, twice over, and the rest
    assert row["training_bytes_estimate"] > row["device_bytes_peak"]   # + Adam moments, the loss, targets
    assert row["crop_triangles"] > 0 and row["crop_share_within_f32_model"] >= 0.99
    assert row["crop_max_abs_error"] < 1e-3


def test_a_size_over_the_binding_limit_is_a_row_naming_the_buffer(ctx):
    from tsplus_wgpu import Renderer
    from tsplus_wgpu.gpu import GpuContext
    small = GpuContext(ctx.adapter)
    small.limits = dict(small.limits, **{"max-storage-buffer-binding-size": 64 * 1024})
    result = scale_report(Renderer(small), [300, 3_000], 64, 48, sh_degree=3)
    ok, over = result["rows"]
    assert "refused" not in ok and result["storage_binding_bytes"] == 64 * 1024
    assert re.match(r"^\w+: needs [\d.]+ MiB in one buffer, over this device's storage-binding limit", over["refused"])


def test_the_command_prints_and_writes_json(tmp_path, capsys):
    from tsplus_wgpu.cli.main import main
    out = tmp_path / "scale.json"
    assert main(["bench-scale", "--vertices", "2k", "3000", "--width", "64", "--height", str(CROP + 16),
                 "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert [r["vertices"] < 3_100 for r in data["rows"]] == [True, True] and data["adapter"]
    assert "kernel layout" in capsys.readouterr().out
    with pytest.raises(SystemExit) as e:
        main(["bench-scale", "--vertices", "lots"])
    assert e.value.code == 2 and "--vertices: expected a vertex count" in capsys.readouterr().err


def test_training_a_size_with_checkpoint_and_resume(renderer):
    from tsplus_wgpu.bench.scale import scale_training
    r = scale_training(renderer, 3000, 96, 64, iterations=6, views=3)
    assert r["iteration"] == 6 and r["vertices"] > 2500 and r["triangles"] > 5000
    assert r["loss_last"] < r["loss_first"]           # from shuffled DC colours towards the model's own renders
    assert r["checkpoint_bytes"] > r["vertices"] * 16 * 12 and r["device_bytes_peak"] > 0
