"""``tsplus train``: train on a scene folder (or the built-in procedural scene) and write the
opaque mesh, held-out metrics, test renders, the log and a resumable checkpoint.

The options that set a :class:`~tsplus_wgpu.train.config.TrainConfig` field come from that
field's metadata (:func:`~tsplus_wgpu.train.config.cli_options`): flag, help and default are
declared once, there. Precedence: a flag on the command line, then the ``--config`` file, then
the preset's default (:func:`~tsplus_wgpu.train.config.preset_defaults`), then the field's.

The preset, the iterations and ``--downscale``, where neither the command line nor the
``--config`` file gives them, come from :mod:`.plan`: a resumed run's own; on a CPU adapter
(lavapipe, llvmpipe) the quick preset at a small size with the iterations that fit about a quarter
of an hour; else the paper preset at full size. The plan is printed before training, and after
the first timed steps a one-line estimate of the run's duration
(:class:`~tsplus_wgpu.train.callbacks.RateEstimate`)."""

from __future__ import annotations

import errno
import os
import sys
import tempfile
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from ..errors import UserError
from ..io.atomic import describe, remove_orphans, write_bytes, write_error, write_image, write_json
from ..train.config import TrainConfig, check_settings, cli_options, load_config_file, preset_defaults
# re-exported (the tests and older callers import them from here)
from .plan import (CPU_MAX_PIXELS, GPU_MAX_SIDE, Plan, cpu_downscale, cpu_iterations, cpu_late_ratio, plan_lines,  # noqa: F401
                   plan_run)
from .plan import slower_machine

#: flag value -> config value, for the fields whose flag does not take the value itself (besides the
#: switches: a flag whose choices are on and off gives a bool)
_FROM_FLAG = {"normals": lambda v: str(Path(v).resolve())}

def add_parser(sub):
    p = sub.add_parser(
        "train", help="train Triangle Splatting+ on a scene and export an opaque, vertex-coloured mesh",
        description="Train on SCENE (a COLMAP / transforms.json / LLFF / photos folder or a video; default: the built-in "
                    "procedural scene, 'procedural:tiny|small|demo' to pick its size) and write to --out: "
                    "mesh.ply (opaque; vertex colours fitted to the training photos, --mesh-colors), metrics.json (held-out PSNR/SSIM), test "
                    "renders, log.jsonl, config.json and checkpoint.npz (--resume continues it bit-identically). "
                    "--normals DIR adds method.md's optional normal loss.")
    p.add_argument("scene", nargs="?", default="procedural:small",
                   help="scene folder (COLMAP, transforms.json, LLFF or a folder of photos: JPEG, PNG, HEIC, ...), a video file (its 100 "
                        "sharpest frames; `tsplus frames` picks another number), or procedural[:tiny|small|demo] "
                        "(default procedural:small)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--config", default=None, metavar="FILE",
                   help="JSON or TOML file with the keys of a run's config.json (iterations, quick, indoor, seed, "
                        "max_vertices, densify_stop_rel, ...); flags given on the command line override it")
    p.add_argument("--preset", choices=["paper", "quick"], default=None,
                   help="paper: method.md's schedules as they are (30k-iteration constants); quick: every schedule "
                        "scaled to --iterations (default paper; on a CPU adapter quick, with --resume the run's own)")
    for name, flag, text, kwargs in cli_options():       # one option per TrainConfig field with a flag
        p.add_argument(flag, dest=name, default=None, help=text.replace("%", "%%"), **kwargs)
    p.add_argument("--downscale", type=int, default=None,
                   help=f"shrink the images by this factor (default: on a GPU 1, or the smallest that leaves a long "
                        f"side of at most {GPU_MAX_SIDE:,} pixels, the paper's; on a CPU adapter the smallest that "
                        f"leaves a training image at most {CPU_MAX_PIXELS:,} pixels; with --resume the run's own)")
    from .scenes import add_images_arg, add_points_arg
    add_images_arg(p)
    add_points_arg(p)
    p.add_argument("--resume", action="store_true",
                   help="continue from OUT/checkpoint.npz (refused when SCENE, --downscale, --images or the data "
                        "differ from the run's)")
    p.add_argument("--overwrite", action="store_true",
                   help="allow replacing what OUT holds: a finished run (mesh.ply, metrics.json) or, without "
                        "--resume, a checkpoint")
    from ..train.ablations import ABLATIONS
    p.add_argument("--ablation", choices=list(ABLATIONS), default=None,
                   help="one of the paper's ablations (Tables 2-3): " + "; ".join(
                       f"{k} = {v[1]}" + (f" ({', '.join(f'{a}={b}' for a, b in v[2].items())})" if v[2] else "")
                       for k, v in ABLATIONS.items())
                   + ". Sets those config keys (hard_prune, weight_prune, sigma_decay, sigma_final, opacity), which "
                     "a --config file may also set; the ablation wins over the file. The pruning rows need "
                     "--topology on (the default)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--adapter", default=None, help="GPU adapter to use (substring of its name)")
    from .view import add_train_view_args
    add_train_view_args(p)
    return p


def _atomic_ply(path, positions, triangles, colors):
    import trimesh
    rgba = np.concatenate([np.round(np.clip(colors, 0, 1) * 255).astype(np.uint8),
                           np.full((len(colors), 1), 255, np.uint8)], axis=1)
    mesh = trimesh.Trimesh(vertices=np.asarray(positions, np.float64), faces=np.asarray(triangles, np.int64),
                           vertex_colors=rgba, process=False)
    write_bytes(path, mesh.export(file_type="ply"))


def resolve_settings(args):
    """The config keys of this invocation before the scene is known (flag > ``--config`` file
    > preset default; ``background`` and ``extra`` are added by :func:`config_for_scene`).
    Sets ``args.seed`` (the scene loader's seed) to the resolved seed."""
    if args.downscale is not None and args.downscale < 1:
        raise ValueError(f"--downscale: expected an integer >= 1, got {args.downscale}")
    file_cfg = load_config_file(args.config) if args.config else {}
    quick = args.preset == "quick" if args.preset is not None else bool(file_cfg.get("quick", False))
    settings = {**preset_defaults(quick), **file_cfg, "quick": quick}
    for name, _, _, kw in cli_options():
        value = getattr(args, name)
        if value is not None:
            switch = kw.get("choices") == ["on", "off"]
            settings[name] = value == "on" if switch else _FROM_FLAG.get(name, lambda v: v)(value)
    settings = check_settings(settings, source="flags")           # the flags' types and ranges, before any work
    settings["indoor"] = bool(settings.get("indoor", False))
    if getattr(args, "ablation", None):
        from ..train.ablations import ablation_overrides
        settings.update(ablation_overrides(args.ablation))
    defaults = TrainConfig()
    if settings["iterations"] < 1:
        raise ValueError(f"--iterations: expected an integer >= 1, got {settings['iterations']}")
    if settings.get("checkpoint_every", defaults.checkpoint_every) < 0:
        raise ValueError(f"--checkpoint-every: expected >= 0, got {settings['checkpoint_every']}")
    args.seed = settings.get("seed", defaults.seed)
    return settings


def config_for_scene(args, settings, scene):
    """The run's :class:`TrainConfig`: ``settings`` with the scene's background unless set, and
    the invocation noted in ``extra``."""
    settings = dict(settings)
    settings["background"] = tuple(float(x) for x in settings.get("background", scene.background))
    from ..train.checkpoint import data_fingerprint, scene_id
    settings["extra"] = {**settings.get("extra", {}), "scene": scene_id(args.scene), "downscale": args.downscale,
                         **({"ablation": args.ablation} if getattr(args, "ablation", None) else {}),
                         **({"config_file": str(args.config)} if args.config else {}),
                         "images": getattr(args, "images", None),
                         **({"points": args.points} if getattr(args, "points", "auto") != "auto" else {}),
                         "scene_warnings": [str(w) for w in getattr(scene, "warnings", None) or ()],
                         "data": data_fingerprint(scene, args.scene, args.downscale, getattr(args, "images", None))}
    return TrainConfig(**settings)


def _check_writable(out: Path):
    """``--out`` can be created and written (probed with a temp folder in its nearest existing
    ancestor, removed at once): one line otherwise, before any heavy work."""
    if out.exists() and not out.is_dir():
        raise UserError(f"--out {out}: exists and is not a folder; choose another --out")
    anc = out.absolute()
    while not anc.exists() and anc != anc.parent:
        anc = anc.parent
    if not anc.is_dir():
        raise UserError(f"--out {out}: {anc} is a file, not a folder; choose another --out")
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".tsplus-probe-", dir=anc))
    except OSError as exc:
        cause = describe(exc)[0] if exc.errno != errno.ENOENT else "cannot create folders there"
        raise UserError(f"--out {out}: cannot write in {anc} ({cause}); choose another --out") from None


def _finished(out: Path):
    return (out / "mesh.ply").is_file() and (out / "metrics.json").is_file()


def _output_folder(args):
    """``(out, checkpoint path, (arrays, meta) of the checkpoint to resume or None)``, every
    check on ``--out`` and ``--resume`` that needs no scene done."""
    if not str(args.out).strip():
        raise UserError("--out: empty; give the output folder (e.g. --out runs/NAME)")
    out = Path(args.out)
    _check_writable(out)
    ckpt = out / "checkpoint.npz"
    if _finished(out) and not args.overwrite:
        raise UserError(f"--out {out}: holds a finished run (mesh.ply, metrics.json); add --overwrite to replace it"
                        f"{' (--resume: re-export it)' if args.resume else ''} or choose another --out")
    if not args.resume:
        if ckpt.exists() and not args.overwrite:
            raise UserError(f"--out {out}: holds a checkpoint already; add --resume to continue it, --overwrite to "
                            f"start over, or choose another --out")
        return out, ckpt, None
    from ..train.checkpoint import check_fingerprint, read_checkpoint, scene_id
    loaded = read_checkpoint(ckpt)
    saved = (loaded[1]["config"].get("extra") or {}).get("data")
    current = dict(scene=scene_id(args.scene), downscale=args.downscale, images=getattr(args, "images", None))
    if args.downscale is None:          # not given: the run's own (plan_run)
        del current["downscale"]
    warning = check_fingerprint(ckpt, saved, current, keys=list(current))
    if warning:
        print(f"warning: {warning}", file=sys.stderr)
    return out, ckpt, loaded


def _prepare(out: Path, fresh):
    """Create ``out``, remove the temp files a killed run left there and the old
    ``metrics.json`` (the folder holds no finished run until the end); starting afresh (in a
    folder with results only with ``--overwrite``), the old run's other results too."""
    try:
        out.mkdir(parents=True, exist_ok=True)
        remove_orphans(out)
        old = [out / "metrics.json"]
        if fresh:
            old += [out / n for n in ("log.jsonl", "checkpoint.npz", "mesh.ply")] + sorted(out.glob("test_*.png"))
        for path in old:
            path.unlink(missing_ok=True)
    except OSError as exc:
        raise write_error(out, exc) from None


def _start(args, cfg, scene, out, ckpt, t0, ctx, plan, loaded=None):
    """The trainer on ``ctx`` (new or resumed from ``loaded``, the checkpoint's ``(arrays,
    meta)``) with config.json written and the start printed: the adapter, the ``plan``, the
    scene and the vertex cap."""
    from ..render.renderer import Renderer
    from ..train.trainer import Trainer
    if loaded is not None:       # the whole data fingerprint, now that the scene is loaded
        from ..train.checkpoint import check_fingerprint
        check_fingerprint(ckpt, (loaded[1]["config"].get("extra") or {}).get("data"), cfg.extra["data"])
    normal_maps = None
    if cfg.normals:
        from ..data.normals import load_normal_maps
        normal_maps = load_normal_maps(scene, cfg.normals)
    renderer = Renderer(ctx)
    if loaded is not None:
        trainer = Trainer.resume(ckpt, scene, cfg, renderer=renderer, normals=normal_maps, loaded=loaded)
    else:
        trainer = Trainer(scene, cfg, renderer=renderer, normals=normal_maps)
    _prepare(out, fresh=loaded is None)
    write_json(out / "config.json", dict(asdict(cfg), adapter=renderer.adapter_name))
    print(f"adapter: {renderer.adapter_name}")
    for line in plan_lines(plan, cfg, scene, trainer.m):
        print(line)
    print(f"scene: {args.scene} ({len(scene.train_indices)} training / {len(scene.test_indices)} held-out views, "
          f"{scene.cameras[0].width}x{scene.cameras[0].height}); model {trainer.n} vertices / {trainer.m} triangles; "
          f"from iteration {trainer.iteration} to {cfg.iterations} (loaded in {time.perf_counter() - t0:.1f}s)")
    info = getattr(trainer, "init_info", None)
    if info is not None:
        carve = (f"{info.num_carved_faces:,} carved as free space by the training views' lines of sight"
                 if cfg.carve and scene.point_tracks is not None else
                 "none carved (" + ("--carve off" if not cfg.carve else "the scene has no SfM tracks") + ")")
        bounded = (f" (of {info.num_input + info.num_bounded:,}: at most {cfg.init_points_share:g} x the vertex cap)"
                   if info.num_bounded else "")
        print(f"initial mesh: {info.num_unique:,} points{bounded}; Delaunay faces: {carve}, {info.num_long_faces:,} "
              f"longer than {cfg.init_max_edge:g} spacings dropped, {info.num_path_faces:,} on the cameras' path "
              + ("dropped" if cfg.clear_path else "kept (--clear-path off)")
              + (f"; {info.num_view_faces:,} faces of the training views' own triangulations added (--view-faces on)"
                 if cfg.view_faces else ""))
    if cfg.topology:
        print(f"vertex cap: {trainer.topology.cap.vertices:,} ({trainer.topology.cap.why})")
    if normal_maps is not None:
        from ..train.schedules import NORMAL_LOSS_AFTER
        print(f"{normal_maps.summary(len(scene.train_indices))}; normal loss weight "
              f"{trainer.sched.normal_loss_weight(cfg.iterations)} from iteration "
              f"{trainer.sched.at(NORMAL_LOSS_AFTER) + 1}")
        for w in normal_maps.warnings:
            print(f"warning: {w}")
    return trainer


def detail_line(info):
    """One line on the colour detail (:mod:`tsplus_wgpu.train.detail`): the level kept and why."""
    if "skipped" in info:
        return f"colour detail: none ({info['skipped']})"
    lv, chosen = info["levels"], info["chosen"]
    tried = ", ".join(f"{x['psnr']:.2f}" for x in lv[1:]) or "none possible within the detail budget"
    if chosen == 0:
        return (f"colour detail: none kept (the {info['held_back']} held-back training views: {lv[0]['psnr']:.2f} dB "
                f"as trained, subdivided {tried} dB)")
    return (f"colour detail: triangles over {lv[chosen]['px']:g} px split, {lv[0]['vertices']:,} -> "
            f"{lv[chosen]['vertices']:,} vertices (the {info['held_back']} held-back training views: "
            f"{lv[0]['psnr']:.2f} dB as trained, {tried} dB at the levels tried)")


def _upright(scene):
    """The scene's up from its cameras (``tsplus export --y-up`` stands the mesh on it), as JSON."""
    from ..data.upright import scene_upright
    up = scene_upright(scene)
    return None if up is None else up.as_dict()


def _bar(progress, desc, unit, total=1):
    """A progress bar with ETA on stderr, shown after a second and cleared when done, or None
    (``--no-progress``)."""
    if not progress:
        return None
    from tqdm import tqdm
    return tqdm(total=total, desc=desc, unit=unit, dynamic_ncols=True, smoothing=0, leave=False, delay=1.0)


def _finish(trainer, scene, out, ckpt, psnr0, progress=True):
    """Export the mesh (first: nothing optional before it), then the checkpoint, the
    evaluation, metrics.json (which marks the run finished) and the test renders; with
    ``progress``, a bar with ETA over the views each part draws."""
    from ..apps.evaluate import evaluate_mesh, mean_coverage
    from ..train.schedules import SUPERSAMPLE_EVAL
    bar = _bar(progress, "export", "view")
    try:
        pos, tri, col = trainer.final_mesh(bar)
    finally:
        if bar is not None:
            bar.close()
    _atomic_ply(out / "mesh.ply", pos, tri, col)
    fin = trainer.final_info
    colours = f"fitted to {fin['color_fit']['views']} training views" if fin["color_fit"] else "from SH DC"
    behind = " and what the shell lost behind the surfaces" if trainer.config.fill_hidden else ""
    print(f"exported mesh: {len(tri):,} triangles, {fin['filled_triangles']:,} of them a backdrop filling holes of "
          f"the training views{behind}; {fin['shards']:,} shards removed ({fin.get('floaters', 0):,} of them on the "
          f"cameras' path, {fin.get('far', 0):,} in front of what the photos show far away, {fin.get('sky', 0):,} in "
          f"front of their sky; {fin.get('shards_kept', 0):,} "
          f"kept, the training views drawn worse without them); vertex colours {colours}")
    if fin.get("detail") is not None:
        print(detail_line(fin["detail"]))
    if fin.get("facing"):
        f = fin["facing"]
        print(f"winding: {f['turned']:,} of {f['triangles']:,} triangles turned to face the training views that draw "
              f"them (their pixels drawn from the front: {100 * f['front_before']:.0f} % -> {100 * f['front_after']:.1f} %)")
    trainer.save_checkpoint(ckpt)
    soft_psnr, soft_ssim, _ = trainer.evaluate()
    views = list(scene.test_indices or trainer.train_views)
    # the exported mesh as an engine draws it (depth-tested MeshRenderer, 4x4 samples): as `tsplus eval`
    imgs, bar = [], _bar(progress, "held-out views", "view", total=len(views))
    try:
        rows = evaluate_mesh(trainer.mesh_model(pos, tri, col), scene, views, trainer.mesh_renderer, SUPERSAMPLE_EVAL,
                             background=tuple(trainer.config.background),
                             near=trainer.frame.near_world(trainer.config.near), renders=imgs,
                             progress=None if bar is None else bar.update)
    finally:
        if bar is not None:
            bar.close()
    psnr_m, ssim_m = (float(np.mean([r[k] for r in rows])) for k in ("psnr", "ssim"))
    coverage = mean_coverage(rows)
    metrics = dict(iterations=trainer.iteration, held_out_views=views, held_out_are_training_views=not scene.test_indices,
                   mesh_psnr=psnr_m, mesh_ssim=ssim_m, mesh_coverage=coverage,
                   model_psnr=soft_psnr, model_ssim=soft_ssim,
                   initial_model_psnr=psnr0, mesh_vertices=int(len(pos)), mesh_triangles=int(len(tri)),
                   model_vertices=trainer.n, model_triangles=trainer.m, train_seconds=trainer.elapsed,
                   iterations_per_s=trainer.iteration / max(trainer.elapsed, 1e-9),
                   shards_removed=int(fin.get("shards", 0)), path_floaters_removed=int(fin.get("floaters", 0)),
                   far_occluders_removed=int(fin.get("far", 0)), sky_triangles_removed=int(fin.get("sky", 0)),
                   shards_kept=int(fin.get("shards_kept", 0)),
                   color_detail=fin.get("detail"), facing=fin.get("facing"), upright=_upright(scene),
                   scene_warnings=[str(w) for w in getattr(scene, "warnings", None) or ()])
    write_json(out / "metrics.json", metrics)
    for v, img in zip(views[:4], imgs[:4]):
        write_image(out / f"test_{v:03d}.png", np.concatenate([scene.images[v], img], axis=1))
    print(f"held-out PSNR {psnr_m:.2f} dB / SSIM {ssim_m:.3f} / coverage {100 * coverage:.1f}% (the exported mesh, "
          f"depth-tested: {len(pos)} vertices, {len(tri)} triangles); trained model {soft_psnr:.2f} dB"
          + (f" (initial {psnr0:.2f} dB)" if psnr0 is not None else ""))
    print(f"wrote {out}/mesh.ply, metrics.json, log.jsonl, checkpoint.npz, test_*.png")


def run(args):
    from tqdm import tqdm

    from ..data.loader import frame_sizes
    from ..gpu.context import GpuContext
    from ..train.callbacks import RateEstimate
    from ..train.loop import Interrupted
    from .scenes import TRAIN_POINTS, load_cli_scene
    resolve_settings(args)                       # every flag and the --config file checked before any work
    out, ckpt, loaded = _output_folder(args)
    t0 = time.perf_counter()
    ctx = GpuContext(args.adapter)
    plan = plan_run(args, ctx.is_cpu, lambda: frame_sizes(args.scene, args.images, not args.no_progress),
                    None if loaded is None else loaded[1]["config"])
    args.preset, args.downscale = plan.preset, plan.downscale
    if plan.iterations is not None:
        args.iterations = plan.iterations
    settings = resolve_settings(args)
    scene = load_cli_scene(args.scene, args.downscale, args.seed, images=args.images,   # prints its warnings
                           points=TRAIN_POINTS[args.points], progress=not args.no_progress)
    if plan.init_points_share is not None:       # the CPU adapter's plan: not every point, for its iterations
        settings["init_points_share"] = plan.init_points_share
    if plan.iterations_from == "CPU adapter":     # what fits a quarter of an hour, now that the scene is known
        settings["iterations"] = cpu_iterations(TrainConfig(**settings), scene)
    cfg = config_for_scene(args, settings, scene)
    trainer = _start(args, cfg, scene, out, ckpt, t0, ctx, plan, loaded)
    del loaded
    from .view import attach_live_viewer
    viewer = attach_live_viewer(trainer, args)   # --view: the live window, drawn between steps
    psnr0 = trainer.evaluate()[0] if trainer.iteration == 0 else None
    cams = [scene.cameras[i] for i in scene.train_indices]
    later = cpu_late_ratio(cfg, cams, trainer.m) if ctx.is_cpu else None     # the time model's shape, on a CPU
    planned = (slower_machine(cfg, scene, trainer.m)        # what fits the plan's time on a slower machine
               if plan.iterations_from == "CPU adapter" and trainer.iteration == 0 else None)
    try:
        trainer.train(out_dir=out, progress=not args.no_progress, checkpoint_at_end=False,   # beside the progress bar
                      callbacks=[RateEstimate(report=tqdm.write, later_cost=later, planned=planned)])
    except Interrupted as exc:
        import signal
        signum = exc.signum or signal.SIGINT
        print(f"tsplus: {exc.signal_name if exc.signum else 'stopped'} at iteration {trainer.iteration}; checkpoint "
              f"saved to {ckpt}; continue with --resume", file=sys.stderr)
        return 128 + int(signum)
    finally:
        if viewer is not None:
            viewer.close()
    try:
        _finish(trainer, scene, out, ckpt, psnr0, progress=not args.no_progress)
    except KeyboardInterrupt as exc:      # Ctrl-C, SIGTERM or SIGHUP during the export: keep the training
        import signal
        signum = getattr(exc, "signum", None) or signal.SIGINT
        trainer.save_checkpoint(ckpt)
        print(f"tsplus: {signal.Signals(signum).name} while exporting the mesh at iteration {trainer.iteration}; "
              f"checkpoint saved to {ckpt}; `--resume` exports it", file=sys.stderr)
        return 128 + int(signum)
    return 0
