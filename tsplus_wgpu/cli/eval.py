"""``tsplus eval``: mesh-based novel-view metrics (held-out views drawn by the depth-tested
mesh renderer), the splatting renderer's PSNR beside them, the connectivity report and the
Poisson baseline."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np

from ..apps.evaluate import evaluate_mesh, mean_coverage, normal_error_summary, poisson_baseline
from .scenes import POINTS_CHOICES, TRAIN_POINTS, add_images_arg, load_cli_scene, scene_warnings
from ..errors import UserError
from ..io.atomic import write_json
from ..apps.runs import load_run
from ..io.export import ExportError, connectivity, connectivity_line
from ..train.trainer import Trainer
from ..types import TriangleModel


def add_parser(sub):
    p = sub.add_parser("eval", help="mesh-based novel-view metrics (PSNR/SSIM) with the depth-tested mesh renderer",
                       description="Draw the held-out views of SCENE with the depth-tested mesh renderer (what an "
                                   "engine shows) and report PSNR/SSIM and coverage (the fraction of pixels the mesh "
                                   "draws) per view and mean (table + JSON), "
                                   "ground truth | render | error heat-map images, the trainer renderer's PSNR on "
                                   "the same views and the connectivity report. `tsplus eval --baseline poisson "
                                   "SCENE` evaluates a Poisson mesh of the scene's points the same way.")
    p.add_argument("inputs", nargs="+", metavar="RUN_OR_MESH SCENE",
                   help="run folder or mesh file, then the scene (folder or procedural[:tiny|small|demo]; default "
                        "for a run: the scene, --downscale and --images it was trained on, from its config.json); "
                        "with --baseline only SCENE")
    p.add_argument("--baseline", choices=["poisson"], default=None, help="evaluate a classical baseline instead")
    p.add_argument("--out", default=None, help="output folder (default RUN/eval, or runs/eval-<name>)")
    p.add_argument("--supersample", type=int, default=4, help="s x s supersampling (default 4, as the paper's eval)")
    p.add_argument("--views", choices=["test", "train", "all"], default="test",
                   help="which views (default test: the held-out ones; training views when there are none)")
    p.add_argument("--downscale", type=int, default=None,
                   help="shrink the scene's images (default 1, or the run's own when SCENE is the scene it was trained on "
                        "or is left out)")
    p.add_argument("--write-images", dest="write_images", type=int, default=4, metavar="N",
                   help="ground truth | render | error images to write (default 4)")
    add_images_arg(p)
    p.add_argument("--no-splat", action="store_true", help="skip the trainer renderer's PSNR column")
    p.add_argument("--interpolation", choices=["perspective", "linear"], default="perspective",
                   help="colour interpolation: perspective-correct as engines (default) or linear in screen space "
                        "as the splatting model")
    p.add_argument("--poisson-depth", type=int, default=9, help="Poisson octree depth (default 9)")
    p.add_argument("--points", default="sfm", choices=POINTS_CHOICES,
                   help="with --baseline: the points the Poisson mesh is built from, as `tsplus train --points` "
                        "takes them (default sfm: the scene's SfM points, triangulated when it has none; auto: the "
                        "points a training run starts from, which on lund give a weaker Poisson mesh, 8.56 against "
                        "11.04 dB)")
    p.add_argument("--normals", default=None, metavar="DIR",
                   help="also report the mesh's normal error against these normal maps (the files and convention of "
                        "`tsplus train --normals`) on the evaluated views that have one: mean 1 - <N, P> and mean "
                        "angle, N the mesh's camera-space normal drawn opaque (sigma 1e-4, the normal loss's render)")
    p.add_argument("--adapter", default=None, help="GPU adapter to use (substring of its name)")
    return p


def _table(rows, has_splat):
    head = f"{'view':>6}  {'name':<24}{'PSNR':>8}{'SSIM':>8}{'coverage':>10}" + \
        (f"{'splat PSNR':>12}" if has_splat else "")
    lines = [head]
    for r in rows:
        lines.append(f"{r['view']:>6}  {r['name'][:23]:<24}{r['psnr']:>8.2f}{r['ssim']:>8.3f}{r['coverage']:>10.1%}"
                     + (f"{r.get('splat_psnr', float('nan')):>12.2f}" if has_splat else ""))
    if rows:
        mp = np.mean([r["psnr"] for r in rows])
        ms = np.mean([r["ssim"] for r in rows])
        extra = f"{np.mean([r['splat_psnr'] for r in rows]):>12.2f}" if has_splat else ""
        lines.append(f"{'mean':>6}  {'':<24}{mp:>8.2f}{ms:>8.3f}{mean_coverage(rows):>10.1%}{extra}")
    return "\n".join(lines)


def _inputs(args):
    """``(run or mesh argument or None, scene argument)`` of the positional inputs."""
    if args.baseline:
        if len(args.inputs) != 1:
            raise UserError("eval --baseline poisson: give only SCENE")
        return None, args.inputs[0]
    if len(args.inputs) == 1:
        return args.inputs[0], None
    if len(args.inputs) != 2:
        raise UserError("eval: expected RUN_OR_MESH SCENE (or --baseline poisson SCENE)")
    return tuple(args.inputs)


def _run_scene(args, run_arg, info):
    """``(scene argument, downscale, images)`` of a run evaluated without SCENE: the scene it was
    trained on (config.json's absolute path), its downscale and image folder unless given."""
    scene = info.get("scene")
    if not scene:
        raise UserError(f"eval: expected RUN_OR_MESH SCENE; {run_arg} does not record the scene it was trained on "
                        f"(no config.json naming it); give SCENE after it")
    if not str(scene).startswith("procedural") and not Path(scene).exists():
        raise UserError(f"eval: {run_arg} was trained on {scene} (its config.json), which does not exist any more; "
                        f"give SCENE after {run_arg}")
    downscale = args.downscale if args.downscale is not None else int(info.get("downscale") or 1)
    images = args.images if args.images is not None else info.get("images")
    return str(scene), downscale, images


def _is_runs_scene(info, scene_arg):
    """Whether ``scene_arg`` names the scene the run (``info``: :func:`~tsplus_wgpu.apps.runs.load_run`'s)
    was trained on: the same argument, or the same folder."""
    scene = info.get("scene")
    if not scene:
        return False
    if str(scene) == str(scene_arg):
        return True
    a, b = Path(str(scene)), Path(str(scene_arg))
    return a.exists() and b.exists() and a.resolve() == b.resolve()


def _as_the_run_held_out(run_arg, info, scene_arg, views):
    """``(views, notes)``: the held-out ``views`` less those the run left out of its own evaluation
    (a held-out photo whose pose disagrees with its matches, :mod:`~tsplus_wgpu.data.heldout_poses`),
    with the run's warning lines about them. That check runs only where the scene's points are
    triangulated, which `tsplus train` does and this load of a COLMAP scene with points does not,
    so without this the two figures of one run could differ. Only for the run's own scene."""
    if run_arg is None or not Path(run_arg).is_dir() or not info.get("scene"):
        return views, []
    same = _is_runs_scene(info, scene_arg)
    try:
        m = json.loads((Path(run_arg) / "metrics.json").read_text())
        rec = {int(v) for v in m["held_out_views"]}
    except (OSError, ValueError, KeyError, TypeError):
        return views, []
    if not same or m.get("held_out_are_training_views") or not rec < set(views):
        return views, []
    notes = [str(w) for w in m.get("scene_warnings", []) if "held-out photo" in str(w)]
    return [v for v in views if v in rec], notes


def _out_folder(args, run_arg):
    """The output folder (created, writable): --out, RUN/eval, or runs/eval-<name>."""
    if args.out:
        out = Path(args.out)
    elif run_arg and Path(run_arg).is_dir():
        out = Path(run_arg) / "eval"
    else:
        name = "poisson" if args.baseline else Path(run_arg).stem
        out = Path("runs") / f"eval-{name}"
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"--out {out}: cannot create the folder ({exc.strerror or exc})") from None
    if not os.access(out, os.W_OK):
        raise UserError(f"--out {out}: permission denied")
    return out


def run(args):
    from ..render.mesh_renderer import MeshRenderer
    if args.supersample < 1:
        raise ValueError(f"--supersample: expected an integer >= 1, got {args.supersample}")
    run_arg, scene_arg = _inputs(args)
    if args.normals and not Path(args.normals).is_dir():     # before anything is written
        raise ExportError(f"--normals {args.normals}: no such folder")
    t0 = time.perf_counter()
    downscale, images = (1 if args.downscale is None else args.downscale), args.images
    if run_arg is not None:
        model, info = load_run(run_arg)
        source = info.get("from")
        if scene_arg is None:
            scene_arg, downscale, images = _run_scene(args, run_arg, info)
            print(f"scene of the run: {scene_arg}" + (f" (--downscale {downscale})" if downscale != 1 else "")
                  + (f" (--images {images})" if images else ""))
        elif _is_runs_scene(info, scene_arg):      # at the size and from the images it was trained on
            _, downscale, images = _run_scene(args, run_arg, info)
            own = [f"--downscale {downscale}"] if args.downscale is None and downscale != 1 else []
            own += [f"--images {images}"] if args.images is None and images else []
            if own:
                print(f"the run's own {' '.join(own)} (its scene; give them to choose others)")
    scene = load_cli_scene(scene_arg, downscale, images=images,     # prints its warnings
                           points=TRAIN_POINTS[args.points] if args.baseline else "auto")
    if args.baseline:
        tb = time.perf_counter()
        model = poisson_baseline(scene, depth=args.poisson_depth)
        source = f"screened Poisson reconstruction of {len(scene.points)} {scene.points_source} points (depth " \
                 f"{args.poisson_depth}, lowest-density 5% trimmed) in {time.perf_counter() - tb:.1f}s"
    # the exported mesh is drawn opaque with its vertex colours: the mesh file's own (what an engine
    # draws; fitted to the photos by `tsplus train`), else the SH DC term (view-independent)
    colors = None if args.baseline or run_arg is None else info.get("colors")
    if colors is None or len(colors) != model.num_vertices:
        model = TriangleModel(model.positions, model.triangles, model.sh[:, :1], np.ones(model.num_vertices))
    else:
        model = Trainer.mesh_model(model.positions, model.triangles, colors)
    if model.num_triangles == 0:
        raise ExportError(f"{run_arg or 'baseline'}: the mesh has no triangles; nothing to evaluate")
    if args.views == "test":
        views = list(scene.test_indices) or list(scene.train_indices)
        if run_arg is not None and not args.baseline:
            kept, notes = _as_the_run_held_out(run_arg, info, scene_arg, views)
            if len(kept) < len(views):
                print(f"held-out views as the run evaluated them: {len(kept)} of {len(views)}; it left out: "
                      + "; ".join(notes or ["(its metrics.json does not say why)"]))
                views = kept
    elif args.views == "train":
        views = list(scene.train_indices)
    else:
        views = list(range(len(scene.cameras)))
    out = _out_folder(args, run_arg)
    splat = None
    mr = MeshRenderer(args.adapter)
    if not args.no_splat:
        from ..render.renderer import Renderer
        splat = Renderer(mr.ctx)
    conn = connectivity(model.triangles, model.num_vertices)
    print(f"adapter: {mr.adapter_name}")
    print(f"mesh: {source}: {model.num_vertices} vertices, {model.num_triangles} triangles")
    print(connectivity_line(conn))
    print(f"scene: {scene_arg}: {len(views)} {'held-out' if args.views == 'test' and scene.test_indices else args.views}"
          f" views, {scene.cameras[0].width}x{scene.cameras[0].height}, supersampling {args.supersample}x"
          f"{args.supersample}")
    bg = tuple(float(x) for x in scene.background)
    rows = evaluate_mesh(model, scene, views, mr, args.supersample, splat, out, args.write_images, bg,
                         args.interpolation)
    print(_table(rows, splat is not None))
    res = dict(mesh=str(run_arg) if run_arg else "baseline:poisson", source=source, scene=scene_arg,
               adapter=mr.adapter_name, supersample=args.supersample, interpolation=args.interpolation, views=rows,
               mean_psnr=float(np.mean([r["psnr"] for r in rows])), mean_ssim=float(np.mean([r["ssim"] for r in rows])),
               mean_coverage=mean_coverage(rows), connectivity=conn, seconds=time.perf_counter() - t0, scene_warnings=scene_warnings(scene))
    if splat is not None:
        res["mean_splat_psnr"] = float(np.mean([r["splat_psnr"] for r in rows]))
        res["splat_note"] = "trainer renderer at sigma 1e-4, opacity 1, no supersampling"
    if getattr(args, "normals", None):
        res["normal_error"] = normal_error_summary(model, scene, views, args.normals, splat or mr.ctx)
    write_json(out / "metrics.json", res)
    print(f"mean render {np.mean([r['render_ms'] for r in rows]):.1f} ms/view; wrote {out}/metrics.json and "
          f"view_*.png (ground truth | render | error)")
    return 0
