"""``tsplus bench --smoke``: the report's structure, every number finite, the plots and the
markdown; a scene that does not load is one line; the cache makes a second run instant.
No timing is asserted."""

import json
import math

import pytest


def _numbers(obj, path="report"):
    if isinstance(obj, bool) or obj is None or isinstance(obj, str):
        return
    if isinstance(obj, (int, float)):
        yield path, obj
    elif isinstance(obj, dict):
        for k, v in obj.items():
            yield from _numbers(v, f"{path}.{k}")
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _numbers(v, f"{path}[{i}]")


@pytest.fixture(scope="module")
def smoke(tmp_path_factory):
    from tsplus_wgpu.cli.main import main
    out = tmp_path_factory.mktemp("bench")
    assert main(["bench", "--smoke", "--out", str(out), "--no-progress"]) == 0
    return out


def test_smoke_report_structure_and_finite(smoke):
    from tsplus_wgpu.train.ablations import ABLATIONS
    from tsplus_wgpu.train.profile import STAGES
    rep = json.loads((smoke / "report.json").read_text())
    bad = [p for p, v in _numbers(rep) if not math.isfinite(v)]
    assert not bad, bad
    # non-finite values would have been written as null: none where a measurement belongs
    m = rep["meta"]
    for key in ("adapter", "commit", "command", "date"):
        assert m[key]
    assert rep["peak"]["median"] > 0 and rep["peak"]["n"] >= 2
    (s,) = rep["scenes"]
    assert s["status"] == "ok" and s["resolution"] == [64, 48]
    runs = s["runs"]
    assert {"quick", "long", "densify-no-stop", "budget-0.5"} | {f"ablation-{a}" for a in ABLATIONS} <= set(runs)
    for name, r in runs.items():
        assert "error" not in r, (name, r.get("error"))
        for key in ("mesh_psnr", "mesh_ssim", "soft_psnr", "soft_ssim", "mesh_vertices", "train_seconds"):
            assert r["final"][key] is not None, (name, key)
    assert [p["iteration"] for p in runs["quick"]["points"]] == [0, 8, 16]
    assert runs["long"]["iterations"] == 32
    st = runs["ablation-baseline"]["stages"]
    assert set(STAGES) <= set(st["ms"]) and all(st["ms"][k] is not None for k in STAGES)
    assert all(st["ms"][k]["min"] <= st["ms"][k]["median"] <= st["ms"][k]["max"] for k in STAGES)
    bl = runs["quick"]["blend"]
    for k in ("forward", "backward"):
        assert bl[k]["fraction_of_peak"] is not None and bl[k]["ms"]["n"] == 2
    assert [r["name"] for r in s["ablations"]] == list(ABLATIONS)
    for r in s["ablations"]:
        assert r["paper_delta"] == ABLATIONS[r["name"]][3]
        assert r["delta_mesh_psnr"] is not None and r["delta_soft_psnr"] is not None
    assert len(s["budgets"]) == 3
    assert s["poisson"]["vertices"] > 0 and s["poisson"]["psnr"] is not None
    for plot in s["plots"]:
        assert (smoke / plot).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(s["plots"]) == 4
    md = (smoke / "report.md").read_text()
    for head in ("## Headline", "Per-stage time", "Blend kernels", "Vertices vs PSNR", "Ablations", m["adapter"],
                 m["commit"], f"kernel layout: {m['layout']}", f"kernel layout {m['layout']}"):
        assert head in md


def test_rerun_uses_cache_and_bad_scene_is_one_line(smoke, tmp_path):
    from tsplus_wgpu.bench.plans import plan_for
    from tsplus_wgpu.bench.runs import Bench
    from tsplus_wgpu.cli.main import main
    # the same command again: every run from the cache
    assert main(["bench", "--smoke", "--out", str(smoke), "--no-progress", "--no-plots"]) == 0
    rep = json.loads((smoke / "report.json").read_text())
    assert all(r["cached"] for r in rep["scenes"][0]["runs"].values())
    # --report-only rewrites the markdown from report.json, numbers kept
    (smoke / "report.md").unlink()
    assert main(["bench", "--out", str(smoke), "--report-only", "--no-plots"]) == 0
    assert json.loads((smoke / "report.json").read_text())["scenes"][0]["runs"]["quick"]["final"] == \
        rep["scenes"][0]["runs"]["quick"]["final"]
    assert "## Headline" in (smoke / "report.md").read_text()
    # a scene that does not load: one record, no exception
    from types import SimpleNamespace
    rec = Bench(tmp_path, SimpleNamespace(ctx=None), None, progress=False).scene(plan_for(str(tmp_path / "nope")))
    assert rec["status"].startswith("error: scene did not load") and "\n" not in rec["status"]


def test_help_and_bad_arguments(tmp_path, capsys):
    from tsplus_wgpu.cli.main import main
    with pytest.raises(SystemExit) as exc:
        main(["bench", "--help"])
    assert exc.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    for word in ("--smoke", "--iterations", "--long-factor", "--budgets", "--fresh", "procedural", "cup", "chair",
                 "min", "TSPLUS_DATA", "ablations"):
        assert word in text, word
    assert main(["bench", "--out", str(tmp_path / "o"), "--iterations", "0"]) == 2
    assert main(["bench", "--out", str(tmp_path / "o"), "--budgets", "-1"]) == 2
    assert "error" in capsys.readouterr().err
