"""One place defines each default: TrainConfig's field metadata builds ``tsplus train``'s options;
the CLI's resolution (flag > --config file > preset default > field default)."""

import json
import math
from dataclasses import asdict, fields
from types import SimpleNamespace

import numpy as np
import pytest

from tsplus_wgpu.cli.main import build_parser
from tsplus_wgpu.cli.train import config_for_scene, load_config_file, resolve_settings
from tsplus_wgpu.errors import UserError
from tsplus_wgpu.train.config import (MAX_ITERATIONS, ConfigError, TrainConfig, check_settings, cli_options,
                                      preset_defaults)

#: a stand-in for a loaded scene: what config_for_scene reads of it
SCENE = SimpleNamespace(background=(0.25, 0.5, 0.75), format="colmap", image_names=["a.png", "b.png"],
                        cameras=[SimpleNamespace(width=4, height=3)] * 2, images=[np.zeros((3, 4, 3))] * 2,
                        points=None, warnings=["skipped images/c.png: not found", "3 points with NaN dropped"])


def _config(*argv):
    args = build_parser().parse_args(["train", "procedural:tiny", "--out", "x", *argv])
    return config_for_scene(args, resolve_settings(args), SCENE), args


def test_every_flag_comes_from_a_field_and_shows_its_default():
    names = {f.name: f for f in fields(TrainConfig)}
    opts = cli_options()
    assert {o[0] for o in opts} == {"iterations", "indoor", "seed", "log_every", "checkpoint_every", "topology",
                                    "max_vertices", "vertex_budget", "densify_stop_rel", "quick_early_prune", "shell", "init_max_edge", "carve", "clear_path", "sh_degree", "final_prune",
                                    "mesh_colors", "fill_holes", "fill_hidden", "remove_shards", "remove_far", "remove_sky", "shard_check", "color_detail",
                                    "detail_budget", "normals", "position_lr_depth", "view_faces"}
    for name, flag, text, _ in opts:
        f = names[name]
        if f.default is not None and not f.metadata["argparse"].get("action"):
            shown = ("on" if f.default else "off") if isinstance(f.default, bool) else f.default
            assert f"default {shown}" in text, (flag, text)
    help_text = build_parser()._subparsers._group_actions[0].choices["train"].format_help()
    for _, flag, _, _ in opts:
        assert flag in help_text


def test_defaults_of_the_library_and_the_command_agree():
    paper, _ = _config()
    quick, _ = _config("--preset", "quick")
    assert (paper.iterations, paper.log_every, paper.checkpoint_every) == (30000, 100, 1000)
    assert (quick.iterations, quick.log_every, quick.checkpoint_every) == (3000, 25, 1000)
    assert paper.background == SCENE.background and paper.topology and quick.topology
    lib = asdict(TrainConfig())
    for key in ("log_every", "checkpoint_every", "iterations", "seed", "max_vertices", "vertex_budget",
                "densify_stop_rel"):
        assert getattr(paper, key) == lib[key], key
    assert asdict(TrainConfig.preset(quick=True)) == {**lib, **preset_defaults(True)}
    assert preset_defaults(True) == dict(quick=True, iterations=3000, log_every=25)


def test_flags_override_the_config_file_which_overrides_the_preset(tmp_path):
    path = tmp_path / "c.json"
    path.write_text(json.dumps(dict(quick=True, iterations=77, log_every=7, seed=3, topology=False,
                                    checkpoint_every=5, densify_stop_rel=0.5)))
    cfg, args = _config("--config", str(path))
    assert (cfg.quick, cfg.iterations, cfg.log_every, cfg.seed, cfg.topology, cfg.checkpoint_every,
            cfg.densify_stop_rel) == (True, 77, 7, 3, False, 5, 0.5)
    assert args.seed == 3 and cfg.extra["config_file"] == str(path)
    cfg, _ = _config("--config", str(path), "--preset", "paper", "--log-every", "9", "--topology", "on",
                     "--densify-stop", "0", "--seed", "8", "--indoor")
    assert (cfg.quick, cfg.iterations, cfg.log_every, cfg.topology, cfg.densify_stop_rel, cfg.seed,
            cfg.indoor) == (False, 77, 9, True, 0.0, 8, True)


# ------------------------------------------------------------------ validation (issue 15)

@pytest.mark.parametrize("key, value", [
    ("max_vertices", -5), ("vertex_budget", -0.5), ("vertex_budget", math.inf), ("vertex_budget", "2"),
    ("vertex_budget", True), ("log_every", -1), ("densify_stop_rel", math.nan), ("densify_stop_rel", 1.5),
    ("background", [2, 0, 0]), ("background", [0.5, 0.5]), ("background", "white"), ("seed", 1.5), ("seed", -1),
    ("iterations", "ten"), ("iterations", 0), ("iterations", 10**12), ("iterations", True), ("quick", "yes"),
    ("indoor", 1), ("sh_degree", 4), ("near", 0.0), ("near", math.inf), ("checkpoint_every", -2),
    ("densify_stop_windows", 0), ("quick_topology_epochs", -1.0), ("quick_opacity_lr_scale", 0),
    ("sigma_final", 0.0), ("sigma_final", 2.0), ("opacity", "clear"), ("normals", ""), ("normals", 3),
    ("extra", [1]), ("topology", "on"),
])
def test_every_field_is_checked_in_the_library(key, value):
    with pytest.raises(ConfigError) as e:
        TrainConfig(**{key: value})
    line = str(e.value)
    assert "\n" not in line and line.startswith(key) and "expected" in line and "got" in line, line
    assert isinstance(e.value, UserError) and isinstance(e.value, ValueError)   # one line in `tsplus`, exit 2


def test_the_line_names_the_flag_and_the_allowed_range():
    with pytest.raises(ConfigError, match=r"^max_vertices \(--max-vertices\): expected an integer in \[0, "):
        TrainConfig(max_vertices=-5)
    with pytest.raises(ConfigError, match=f"iterations.*in \\[1, {MAX_ITERATIONS}\\], got 1000000000000"):
        TrainConfig(iterations=10**12)


def test_valid_values_are_converted_to_the_field_types():
    cfg = TrainConfig(background=[1, 0, 0.5], densify_stop_rel=0, seed=np.int64(4), quick_opacity_lr_scale=1,
                      normals=None, indoor=np.bool_(True))
    assert cfg.background == (1.0, 0.0, 0.5) and all(type(x) is float for x in cfg.background)
    assert type(cfg.densify_stop_rel) is float and type(cfg.seed) is int and cfg.seed == 4
    assert type(cfg.quick_opacity_lr_scale) is float and cfg.indoor is True
    # every default and the quick preset are valid; a run's config.json reads back unchanged
    assert check_settings(asdict(TrainConfig.preset(quick=True))) == asdict(TrainConfig.preset(quick=True))


def _flag_error(*argv):
    with pytest.raises(ConfigError) as e:
        _config(*argv)
    return str(e.value)


@pytest.mark.parametrize("argv, words", [
    (("--max-vertices", "-5"), ("--max-vertices:", "got -5", "in [0, 2147483647]")),
    (("--vertex-budget", "-1"), ("--vertex-budget:", "finite number >= 0", "got -1.0")),
    (("--vertex-budget", "nan"), ("--vertex-budget:", "finite number >= 0", "nan")),
    (("--log-every", "-1"), ("--log-every:", ">= 0", "got -1")),
    (("--densify-stop", "nan"), ("--densify-stop:", "finite", "[0, 1]", "nan")),
    (("--iterations", str(10**12)), ("--iterations:", str(MAX_ITERATIONS))),
    (("--iterations", "0"), ("--iterations:", "[1, ")),
    (("--seed", "-3"), ("--seed:", "got -3")),
    (("--checkpoint-every", "-1"), ("--checkpoint-every:", ">= 0", "got -1")),
])
def test_bad_flags_are_one_line_naming_the_flag(argv, words):
    line = _flag_error(*argv)
    assert "\n" not in line and line.startswith(words[0]) and all(w in line for w in words), line


@pytest.mark.parametrize("text, suffix, words", [
    ("background = [2, 0, 0]\n", ".toml", ("background", "[0, 1]", "[2, 0, 0]")),
    ("seed = 1.5\n", ".toml", ("seed", "integer", "1.5")),
    ('iterations = "ten"\n', ".toml", ("iterations", "integer", "'ten'", str(MAX_ITERATIONS))),
    ("[schedule]\nx = 1\n", ".toml", ("unknown table 'schedule'", "iterations")),
    ("itrations = 3\n", ".toml", ("unknown key 'itrations'", "did you mean 'iterations'")),
    ('{"max_vertices": -5}', ".json", ("max_vertices", "-5")),
    ('{"log_every": -1, "densify_stop_rel": 0.1}', ".json", ("log_every", "-1")),
    ('{"iterations": 1e12}', ".json", ("iterations", "integer")),
    ('normals = "/nonexistent/normals"\n', ".toml", ("normals", "existing folder", "/nonexistent/normals")),
])
def test_bad_config_files_are_one_line_naming_the_file_and_key(tmp_path, text, suffix, words):
    path = tmp_path / f"run{suffix}"
    path.write_text(text)
    with pytest.raises(ConfigError) as e:
        load_config_file(path)
    line = str(e.value)
    assert "\n" not in line and line.startswith(f"--config {path}: ") and all(w in line for w in words), line
    with pytest.raises(ConfigError):          # and through the command's resolution, before any scene is loaded
        _config("--config", str(path))


def test_a_runs_config_json_is_a_valid_config_file(tmp_path):
    cfg, _ = _config("--preset", "quick", "--iterations", "50")
    path = tmp_path / "config.json"
    path.write_text(json.dumps(dict(asdict(cfg), adapter="lavapipe")))
    again, _ = _config("--config", str(path))
    assert (again.iterations, again.quick, again.background) == (50, True, cfg.background)


def test_the_scene_warnings_and_image_folder_are_recorded(tmp_path):
    cfg, args = _config("--images", "images_4")
    assert args.images == "images_4" and cfg.extra["images"] == "images_4"
    assert cfg.extra["scene_warnings"] == SCENE.warnings
    json.dumps(asdict(cfg))                   # config.json can hold it


def test_the_normals_folder_must_exist_on_the_command_line_not_in_the_library(tmp_path):
    assert TrainConfig(normals="/nonexistent/normals").normals == "/nonexistent/normals"   # a checkpoint's config
    assert "--normals: expected an existing folder" in _flag_error("--normals", str(tmp_path / "nope"))
    cfg, _ = _config("--normals", str(tmp_path))
    assert cfg.normals == str(tmp_path.resolve())


def test_a_checkpoint_from_before_the_early_prune_resumes_without_it():
    """A checkpoint's config lacking ``quick_early_prune`` was trained without it: resuming keeps it
    off (a field new since then otherwise takes its default); one that has it keeps its own."""
    from tsplus_wgpu.train.checkpoint import resume_config
    saved = asdict(TrainConfig.preset(quick=True))
    old = {k: v for k, v in saved.items() if k != "quick_early_prune"}
    assert TrainConfig.preset(quick=True).quick_early_prune
    assert resume_config({"config": old}).quick_early_prune is False
    assert resume_config({"config": saved}).quick_early_prune is True
    with pytest.raises(ValueError, match="quick_early_prune False .*pass --early-prune off to continue it"):
        resume_config({"config": old}, TrainConfig.preset(quick=True))


def test_every_on_off_flag_sets_its_switch():
    """Every boolean field's flag takes on and off (none left out of the conversion to bool)."""
    switches = [(name, flag) for name, flag, _, kw in cli_options() if kw.get("choices") == ["on", "off"]]
    bools = {f.name for f in fields(TrainConfig) if isinstance(f.default, bool) and f.metadata.get("flag")}
    assert {name for name, _ in switches} == bools - {"indoor"} and "quick_early_prune" in bools
    for name, flag in switches:
        for word, want in (("on", True), ("off", False)):
            args = build_parser().parse_args(["train", "procedural:tiny", "--out", "x", flag, word])
            assert resolve_settings(args)[name] is want, (flag, word)
