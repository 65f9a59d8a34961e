"""``tsplus bench-step`` (tsplus_wgpu/bench/step.py) on a few steps: the report's fields, both
modes train to bit-identical parameters, the caches make fewer bind groups than dispatches, and
the command's JSON and its argument error. No timing is asserted."""

import json


def test_the_command_prints_and_writes_json(tmp_path, capsys):
    from tsplus_wgpu.cli.main import main
    out = tmp_path / "step.json"
    assert main(["bench-step", "--steps", "3", "--blocks", "2", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["identical_parameters"] is True and data["adapter"]
    assert data["ms_per_step_caches_on"] > 0 and data["ms_per_step_caches_off"] > 0
    assert len(data["blocks_on"]) == len(data["blocks_off"]) == 2
    # a step dispatches about 80 kernels; with the caches most of their bind groups are found
    assert 0 < data["bind_groups_made_per_step"] < 40 and 0 < data["uniforms_made_per_step"] < 40
    assert "bit-identical" in capsys.readouterr().out
    assert main(["bench-step", "--points", "2"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("tsplus: error: --points: at least 4") and "Traceback" not in err
