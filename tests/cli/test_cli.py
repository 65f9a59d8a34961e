"""The tsplus command: help, the main job, the benchmark's output structure, errors."""

import json
import math
import subprocess
import sys

import pytest

from tsplus_wgpu.cli.main import COMMANDS, main


def run(*args):
    return subprocess.run([sys.executable, "-m", "tsplus_wgpu.cli", *args], capture_output=True, text=True,
                          timeout=600)


def test_help_lists_commands():
    out = run("--help")
    assert out.returncode == 0
    for cmd in ("render", "bench-raster", "adapters", "inspect"):
        assert cmd in out.stdout
    for cmd in ("render", "bench-raster", "bench-backward", "train", "inspect"):
        sub = run(cmd, "--help")
        assert sub.returncode == 0 and "usage: tsplus " + cmd in sub.stdout


@pytest.mark.parametrize("cmd", sorted(COMMANDS))
def test_every_command_has_help(cmd, capsys):
    """Every command of the table answers ``--help`` with its usage and a description, and the
    top-level help names it."""
    with pytest.raises(SystemExit) as exit_:
        main([cmd, "--help"])
    assert exit_.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: tsplus " + cmd) and len(out.splitlines()) > 5
    assert "option_strings" not in out      # a help text's unescaped % formats the argparse record
    with pytest.raises(SystemExit):
        main(["--help"])
    assert cmd in capsys.readouterr().out


def test_train_help_shows_every_option_as_written(capsys):
    """Every training option's help text reaches ``tsplus train --help`` as written: argparse
    formats help with ``%``, so an unescaped ``7 % shorter`` once printed the option's whole
    argparse record in its place."""
    from tsplus_wgpu.train.config import cli_options
    with pytest.raises(SystemExit):
        main(["train", "--help"])
    shown = "".join(capsys.readouterr().out.split())
    assert "option_strings" not in shown
    with_percent = 0
    for _name, flag, text, _kw in cli_options():
        assert "".join(text.split()) in shown, flag
        with_percent += "%" in text
    assert with_percent >= 1        # the case this guards is present


def test_render_main_job(tmp_path, capsys):
    assert main(["render", "--size", "tiny", "--out", str(tmp_path)]) == 0
    text = capsys.readouterr().out
    assert "rasterize_forward" in text and "PSNR" in text
    psnr = float(text.split("mean ")[1].split(" dB")[0])
    assert psnr > 15.0      # the vertex-coloured mesh resembles the textured reference
    assert (tmp_path / "view_000.png").is_file()
    assert not list(tmp_path.glob("*.tmp*"))


def test_bench_raster_writes_finite_report(tmp_path, capsys):
    out = tmp_path / "r.json"
    assert main(["bench-raster", "--triangles", "500", "2000", "--width", "64", "--height", "48",
                 "--repeats", "2", "--json", str(out), "--layout", "gpu"]) == 0
    rep = json.loads(out.read_text())
    assert rep["adapter"] and rep["peak"]["flops_per_s"] > 0
    assert rep["layout"].startswith("gpu (forward 256 invocations a 16x16 tile, 1 px each")
    assert "kernel layout: gpu (" in capsys.readouterr().out
    assert [r["triangles"] for r in rep["rows"]] == [500, 2000]
    for r in rep["rows"]:
        assert "rasterize_forward" in r["stage_ms_median"]
        for v in (r["gpu_ms_median"], r["triangles_per_s"], r["evals_per_s"], r["blend_flops_per_s"],
                  r["max_abs_error_vs_twin"]):
            assert math.isfinite(v)
        assert r["max_abs_error_vs_twin"] < 1e-3


def test_errors_are_one_line(tmp_path):
    out = run("render", "--sigma", "-1", "--size", "tiny", "--out", str(tmp_path))
    assert out.returncode == 2
    assert out.stderr.strip().count("\n") == 0 and "sigma" in out.stderr and "Traceback" not in out.stderr
    out = run("render", "--adapter", "no-such-gpu-xyz", "--size", "tiny", "--out", str(tmp_path))
    assert out.returncode == 2 and "matches no adapter" in out.stderr and "Traceback" not in out.stderr


def test_adapters_lists_lavapipe_or_gpu(capsys, monkeypatch):
    import re
    assert main(["adapters"]) == 0
    out = capsys.readouterr().out
    assert "*" in out and re.search(r"[\d,]+ MiB per binding, [\d,]+ MiB per buffer", out)
    monkeypatch.setenv("TSPLUS_WEBGPU_LIMITS", "1")      # what a device gets then: WebGPU's sizes
    assert main(["adapters"]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert re.search(r"128 MiB per binding, 256 MiB per buffer, (cpu|gpu) kernel layout$", first)
    monkeypatch.setenv("TSPLUS_LAYOUT", "gpu")          # the override, for every adapter
    assert main(["adapters"]) == 0
    assert capsys.readouterr().out.splitlines()[0].endswith(", gpu kernel layout")
