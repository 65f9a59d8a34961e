"""``tsplus train``: train on a scene folder (or the built-in procedural scene) and write the
opaque mesh, held-out metrics, test renders, the log and a resumable checkpoint."""

from __future__ import annotations

import json
import os
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

#: ``--topology`` default of ``--preset quick`` (measured: see the --topology help and README)
QUICK_TOPOLOGY = True


def add_train_parser(sub):
    p = sub.add_parser(
        "train", help="train Triangle Splatting+ on a scene and export an opaque, vertex-coloured mesh",
        description="Train on SCENE (a COLMAP / transforms.json / LLFF / photos folder; default: the built-in "
                    "procedural scene, 'procedural:tiny|small|demo' to pick its size) and write to --out: "
                    "mesh.ply (opaque, vertex colours from SH DC), metrics.json (held-out PSNR/SSIM), test "
                    "renders, log.jsonl, config.json and checkpoint.npz (--resume continues it bit-identically). "
                    "--normals DIR adds method.md's optional normal loss.")
    p.add_argument("scene", nargs="?", default="procedural:small",
                   help="scene folder, or procedural[:tiny|small|demo] (default procedural:small)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--config", default=None, metavar="FILE",
                   help="JSON or TOML file with the keys of a run's config.json (iterations, quick, indoor, seed, "
                        "max_vertices, densify_stop_rel, ...); flags given on the command line override it")
    p.add_argument("--preset", choices=["paper", "quick"], default=None,
                   help="paper: method.md's schedules as they are (30k-iteration constants); quick: every schedule "
                        "scaled to --iterations (default paper)")
    p.add_argument("--iterations", type=int, default=None, help="iterations (default 30000, quick: 3000)")
    p.add_argument("--seed", type=int, default=None, help="seed of the view order (default 0)")
    p.add_argument("--downscale", type=int, default=1, help="shrink the images by this factor (default 1)")
    p.add_argument("--indoor", action="store_const", const=True, default=None, help="the indoor constants of method.md")
    p.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.npz")
    p.add_argument("--log-every", type=int, default=None, help="iterations between log lines (default 100, "
                                                                  "quick: 25)")
    p.add_argument("--checkpoint-every", type=int, default=None, help="iterations between checkpoints (0: only at "
                                                                       "the end or on Ctrl-C; default 1000)")
    p.add_argument("--max-vertices", type=int, default=None, help="densification cap (default 3000000, method.md)")
    p.add_argument("--densify-stop", type=float, default=None,
                   help="stop densifying when the mean training L1 of the last 3 topology windows improved by less "
                        "than this fraction on the 3 before (default 0.01; 0: never)")
    p.add_argument("--topology", choices=["on", "off"], default=None,
                   help="pruning and densification during training (the final cleanup runs either way); default on. "
                        "The quick preset keeps at least 3 epochs between topology events and a 10x opacity learning "
                        "rate (config keys quick_topology_epochs, quick_opacity_lr_scale) so that opacities separate "
                        "before a prune. Measured on procedural:small, quick, 3000 iterations: held-out mesh PSNR "
                        "25.56 dB with topology vs 22.14 dB without; on runs of a few hundred iterations on a tiny "
                        "scene it does not pay off (tiny, 600: 20.91 on vs 21.92 dB off): use off there")
    from .ablations import ABLATIONS
    p.add_argument("--ablation", choices=list(ABLATIONS), default=None,
                   help="one of the paper's ablations (Tables 2-3): " + "; ".join(
                       f"{k} = {v[1]}" + (f" ({', '.join(f'{a}={b}' for a, b in v[2].items())})" if v[2] else "")
                       for k, v in ABLATIONS.items())
                   + ". Sets those config keys (hard_prune, weight_prune, sigma_decay, sigma_final, opacity), which "
                     "a --config file may also set; the ablation wins over the file. The pruning rows need "
                     "--topology on (the default)")
    p.add_argument("--normals", default=None, metavar="DIR",
                   help="normal-map priors: add the normal loss 0.05 (indoor 0.025) * mean(1 - <N_rendered, N_prior>) "
                        "for iterations > 5000 (scaled with --preset quick) on the training views that have a map "
                        "(off without --normals; views without a map get none, the count is printed). One file per "
                        "view named like its image with .npy (float [H, W, 3], the normal) or .png (8/16-bit, "
                        "rgb = (n + 1) / 2, alpha 0 = no prior); normals in the view's camera space, OpenCV axes "
                        "(x right, y down, z forward), facing the camera (z mostly < 0); pixels whose normal is "
                        "(near) zero, black or masked are ignored; other sizes are area-resized with a warning. "
                        "`tsplus inspect procedural:tiny --write-normals DIR` writes the procedural scene's true maps")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--adapter", default=None, help="GPU adapter to use (substring of its name)")
    from ..viewer_cli import add_train_view_args
    add_train_view_args(p)
    return p


def _atomic_json(path, obj):
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    tmp.write_text(json.dumps(obj, indent=2) + "\n")
    os.replace(tmp, path)


def _atomic_ply(path, positions, triangles, colors):
    import trimesh
    path = Path(path)
    rgba = np.concatenate([np.round(np.clip(colors, 0, 1) * 255).astype(np.uint8),
                           np.full((len(colors), 1), 255, np.uint8)], axis=1)
    mesh = trimesh.Trimesh(vertices=np.asarray(positions, np.float64), faces=np.asarray(triangles, np.int64),
                           vertex_colors=rgba, process=False)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    tmp.write_bytes(mesh.export(file_type="ply"))
    os.replace(tmp, path)


def _load(scene_arg, downscale, seed):
    from ..data import load_procedural, load_scene
    if scene_arg is None or scene_arg.startswith("procedural"):
        size = scene_arg.split(":", 1)[1] if scene_arg and ":" in scene_arg else "small"
        if downscale != 1:
            raise ValueError("--downscale: the procedural scene has fixed sizes; use procedural:tiny|small|demo")
        return load_procedural(size, seed=0)
    if not Path(scene_arg).exists():
        raise FileNotFoundError(f"scene {scene_arg}: no such file or folder")
    return load_scene(scene_arg, downscale=downscale, seed=seed)


def load_config_file(path):
    """The keys of a ``--config`` file (JSON, or TOML by its ``.toml`` suffix), checked
    against :class:`~.trainer.TrainConfig`'s fields (``adapter``, written to config.json, is
    ignored)."""
    from dataclasses import fields
    from .trainer import TrainConfig
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"--config {path}: no such file")
    try:
        if path.suffix.lower() == ".toml":
            import tomllib
            data = tomllib.loads(path.read_text())
        else:
            data = json.loads(path.read_text())
    except Exception as exc:
        raise ValueError(f"--config {path}: not valid {'TOML' if path.suffix.lower() == '.toml' else 'JSON'} "
                         f"({exc})") from None
    if not isinstance(data, dict):
        raise ValueError(f"--config {path}: expected a table of settings")
    known = {f.name for f in fields(TrainConfig)}
    unknown = sorted(set(data) - known - {"adapter"})
    if unknown:
        raise ValueError(f"--config {path}: unknown keys {unknown}; known: {sorted(known)}")
    data.pop("adapter", None)
    return data


def run_train(args):
    from ..cli import atomic_write_image
    from ..renderer import Renderer
    from .trainer import TrainConfig, Trainer
    if args.downscale < 1:
        raise ValueError(f"--downscale: expected an integer >= 1, got {args.downscale}")
    file_cfg = load_config_file(args.config) if args.config else {}

    def pick(flag, key, default):
        return flag if flag is not None else file_cfg.get(key, default)

    quick = args.preset == "quick" if args.preset is not None else bool(file_cfg.get("quick", False))
    iterations = pick(args.iterations, "iterations", 3000 if quick else 30000)
    args.seed = pick(args.seed, "seed", 0)
    args.indoor = bool(pick(args.indoor, "indoor", False))
    args.checkpoint_every = pick(args.checkpoint_every, "checkpoint_every", 1000)
    if iterations < 1:
        raise ValueError(f"--iterations: expected an integer >= 1, got {iterations}")
    if args.checkpoint_every < 0:
        raise ValueError(f"--checkpoint-every: expected >= 0, got {args.checkpoint_every}")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: exists and is not a folder")
    ckpt = out / "checkpoint.npz"
    if not args.resume and ckpt.exists():
        raise ValueError(f"--out {out}: holds a checkpoint already; add --resume to continue it or choose another "
                        f"folder")
    log_every = pick(args.log_every, "log_every", 25 if quick else 100)
    t0 = time.perf_counter()
    scene = _load(args.scene, args.downscale, args.seed)
    settings = {**file_cfg, **dict(iterations=iterations, quick=quick, indoor=args.indoor, seed=args.seed,
                                   log_every=log_every, checkpoint_every=args.checkpoint_every)}
    settings.setdefault("background", scene.background)
    settings["background"] = tuple(float(x) for x in settings["background"])
    settings.setdefault("topology", QUICK_TOPOLOGY if quick else True)
    for key, flag in (("max_vertices", args.max_vertices), ("densify_stop_rel", args.densify_stop),
                      ("topology", None if args.topology is None else args.topology == "on")):
        if flag is not None:
            settings[key] = flag
    if getattr(args, "ablation", None):
        from .ablations import ablation_overrides
        settings.update(ablation_overrides(args.ablation))
    settings["extra"] = {**settings.get("extra", {}), "scene": str(args.scene), "downscale": args.downscale,
                         **({"ablation": args.ablation} if getattr(args, "ablation", None) else {}),
                         **({"config_file": str(args.config)} if args.config else {})}
    if getattr(args, "normals", None):
        settings["normals"] = str(Path(args.normals).resolve())
    cfg = TrainConfig(**settings)
    normal_maps = None
    if cfg.normals:
        from ..data.normals import load_normal_maps
        normal_maps = load_normal_maps(scene, cfg.normals)
    renderer = Renderer(args.adapter)
    out.mkdir(parents=True, exist_ok=True)
    if args.resume:
        trainer = Trainer.resume(ckpt, scene, cfg, renderer=renderer, normals=normal_maps)
    else:
        trainer = Trainer(scene, cfg, renderer=renderer, normals=normal_maps)
        (out / "log.jsonl").unlink(missing_ok=True)
    _atomic_json(out / "config.json", dict(asdict(cfg), adapter=renderer.adapter_name))
    print(f"adapter: {renderer.adapter_name}")
    print(f"scene: {args.scene} ({len(scene.train_indices)} training / {len(scene.test_indices)} held-out views, "
          f"{scene.cameras[0].width}x{scene.cameras[0].height}); model {trainer.n} vertices / {trainer.m} triangles; "
          f"from iteration {trainer.iteration} to {iterations} (loaded in {time.perf_counter() - t0:.1f}s)")
    if normal_maps is not None:
        from .schedules import NORMAL_LOSS_AFTER
        print(f"{normal_maps.summary(len(scene.train_indices))}; normal loss weight "
              f"{trainer.sched.normal_loss_weight(iterations)} from iteration {trainer.sched.at(NORMAL_LOSS_AFTER) + 1}")
        for w in normal_maps.warnings:
            print(f"warning: {w}")
    from ..viewer_cli import attach_live_viewer
    viewer = attach_live_viewer(trainer, args, scene)   # --view: the live window, drawn between steps
    psnr0 = None
    if trainer.iteration == 0:
        psnr0 = trainer.evaluate()[0]
    try:
        trainer.train(out_dir=out, progress=not args.no_progress)
    except KeyboardInterrupt:
        print(f"tsplus: interrupted at iteration {trainer.iteration}; checkpoint saved to {ckpt} "
              f"(continue with --resume)")
        return 130
    finally:
        if viewer is not None:
            viewer.close()
    soft_psnr, soft_ssim, _ = trainer.evaluate()
    pos, tri, col = trainer.final_mesh()
    mesh_model = Trainer.mesh_model(pos, tri, col)
    from .schedules import SIGMA_FINAL
    views = list(scene.test_indices or trainer.train_views)
    psnr_m, ssim_m, imgs = trainer.evaluate(mesh_model, sigma=SIGMA_FINAL, views=views)
    _atomic_ply(out / "mesh.ply", pos, tri, col)
    for i, (v, img) in enumerate(zip(views[:4], imgs[:4])):
        atomic_write_image(out / f"test_{v:03d}.png", np.concatenate([scene.images[v], img], axis=1))
    metrics = dict(iterations=trainer.iteration, held_out_views=views, held_out_are_training_views=not scene.test_indices,
                   mesh_psnr=psnr_m, mesh_ssim=ssim_m, model_psnr=soft_psnr, model_ssim=soft_ssim,
                   initial_model_psnr=psnr0, mesh_vertices=int(len(pos)), mesh_triangles=int(len(tri)),
                   model_vertices=trainer.n, model_triangles=trainer.m, train_seconds=trainer.elapsed,
                   iterations_per_s=trainer.iteration / max(trainer.elapsed, 1e-9))
    _atomic_json(out / "metrics.json", metrics)
    print(f"held-out PSNR {psnr_m:.2f} dB / SSIM {ssim_m:.3f} (opaque mesh: {len(pos)} vertices, {len(tri)} "
          f"triangles); trained model before the final cleanup {soft_psnr:.2f} dB"
          + (f" (initial {psnr0:.2f} dB)" if psnr0 is not None else ""))
    print(f"wrote {out}/mesh.ply, metrics.json, log.jsonl, checkpoint.npz, test_*.png")
    return 0
