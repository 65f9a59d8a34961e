"""One place defines each default: TrainConfig's field metadata builds ``tsplus train``'s options;
the CLI's resolution (flag > --config file > preset default > field default)."""

import json
from dataclasses import asdict, fields
from types import SimpleNamespace

from tsplus_wgpu.cli.main import build_parser
from tsplus_wgpu.cli.train import config_for_scene, resolve_settings
from tsplus_wgpu.train.config import TrainConfig, cli_options, preset_defaults

SCENE = SimpleNamespace(background=(0.25, 0.5, 0.75))


def _config(*argv):
    args = build_parser().parse_args(["train", "procedural:tiny", "--out", "x", *argv])
    return config_for_scene(args, resolve_settings(args), SCENE), args


def test_every_flag_comes_from_a_field_and_shows_its_default():
    names = {f.name: f for f in fields(TrainConfig)}
    opts = cli_options()
    assert {o[0] for o in opts} == {"iterations", "indoor", "seed", "log_every", "checkpoint_every", "topology",
                                    "max_vertices", "densify_stop_rel", "normals"}
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
    for key in ("log_every", "checkpoint_every", "iterations", "seed", "max_vertices", "densify_stop_rel"):
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
