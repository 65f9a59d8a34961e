"""``tsplus export`` and ``tsplus eval``: engine-ready files and mesh-based novel-view metrics
(held-out views drawn by the depth-tested :class:`~tsplus_wgpu.MeshRenderer`), with the
splatting renderer's PSNR beside them, the connectivity report and the Poisson baseline."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np

from .export import BAKES, FORMATS, ExportError, connectivity, connectivity_line, load_run

SIGMA_OPAQUE = 1e-4


def add_parsers(sub):
    p = sub.add_parser("export", help="write a trained run (or a mesh) as PLY / GLB / OBJ",
                       description="Write RUN (a folder written by `tsplus train`, a .ply/.glb/.obj mesh or a "
                                   "checkpoint .npz) as PLY (float32 positions, uint8 RGB, full SH and opacity as "
                                   "extra vertex properties; reads back losslessly), GLB (glTF 2.0 with COLOR_0) or "
                                   "OBJ (vertex colours). Written atomically; prints the connectivity report.")
    p.add_argument("run", help="run folder, mesh file or checkpoint")
    p.add_argument("--format", default=None, help="ply, glb or obj (default: --out's extension, else ply)")
    p.add_argument("--out", default=None, help="output file (default: RUN/mesh_export.FORMAT, or beside the mesh)")
    p.add_argument("--y-up", action="store_true", help="convert the OpenCV world (y down) to y up: (x, -y, -z)")
    p.add_argument("--bake", choices=BAKES, default="dc",
                   help="vertex colour: dc (SH DC term, default) or views (averaged over the training views where "
                        "the vertex is visible; needs the run's scene or --scene)")
    p.add_argument("--scene", default=None, help="scene for --bake views (default: the run's)")
    p.add_argument("--adapter", default=None, help="GPU adapter to use (substring of its name)")

    p = sub.add_parser("eval", help="mesh-based novel-view metrics (PSNR/SSIM) with the depth-tested mesh renderer",
                       description="Draw the held-out views of SCENE with the depth-tested mesh renderer (what an "
                                   "engine shows) and report PSNR/SSIM per view and mean (table + JSON), "
                                   "ground truth | render | error heat-map images, the trainer renderer's PSNR on "
                                   "the same views and the connectivity report. `tsplus eval --baseline poisson "
                                   "SCENE` evaluates a Poisson mesh of the scene's SfM points the same way.")
    p.add_argument("inputs", nargs="+", metavar="RUN_OR_MESH SCENE",
                   help="run folder or mesh file, then the scene (folder or procedural[:tiny|small|demo]); with "
                        "--baseline only SCENE")
    p.add_argument("--baseline", choices=["poisson"], default=None, help="evaluate a classical baseline instead")
    p.add_argument("--out", default=None, help="output folder (default RUN/eval, or runs/eval-<name>)")
    p.add_argument("--supersample", type=int, default=4, help="s x s supersampling (default 4, as the paper's eval)")
    p.add_argument("--views", choices=["test", "train", "all"], default="test",
                   help="which views (default test: the held-out ones; training views when there are none)")
    p.add_argument("--downscale", type=int, default=1, help="shrink the scene's images (default 1)")
    p.add_argument("--images", type=int, default=4, help="side-by-side images to write (default 4)")
    p.add_argument("--no-splat", action="store_true", help="skip the trainer renderer's PSNR column")
    p.add_argument("--interpolation", choices=["perspective", "linear"], default="perspective",
                   help="colour interpolation: perspective-correct as engines (default) or linear in screen space "
                        "as the splatting model")
    p.add_argument("--poisson-depth", type=int, default=8, help="Poisson octree depth (default 8)")
    p.add_argument("--normals", default=None, metavar="DIR",
                   help="also report the mesh's normal error against these normal maps (the files and convention of "
                        "`tsplus train --normals`) on the evaluated views that have one: mean 1 - <N, P> and mean "
                        "angle, N the mesh's camera-space normal drawn opaque (sigma 1e-4, the normal loss's render)")
    p.add_argument("--adapter", default=None, help="GPU adapter to use (substring of its name)")


def load_scene_arg(scene_arg, downscale=1):
    from .data import load_procedural, load_scene
    if scene_arg.startswith("procedural"):
        size = scene_arg.split(":", 1)[1] if ":" in scene_arg else "small"
        if downscale != 1:
            raise ValueError("--downscale: the procedural scene has fixed sizes; use procedural:tiny|small|demo")
        return load_procedural(size, seed=0)
    if not Path(scene_arg).exists():
        raise FileNotFoundError(f"scene {scene_arg}: no such file or folder")
    return load_scene(scene_arg, downscale=downscale)


# ----------------------------------------------------------------------------- export

def run_export(args):
    from .export import bake_views, export
    model, info = load_run(args.run)
    fmt = args.format
    if fmt is None:
        fmt = Path(args.out).suffix.lstrip(".").lower() if args.out else "ply"
    fmt = fmt.lower()
    if fmt not in FORMATS:
        raise ExportError(f"--format {fmt or '(none)'}: unknown format; choose one of {', '.join(FORMATS)}")
    if model.num_triangles == 0:
        raise ExportError(f"{args.run}: the mesh has no triangles; nothing to export")
    run = Path(args.run)
    out = Path(args.out) if args.out else (run / f"mesh_export.{fmt}" if run.is_dir()
                                           else run.with_name(f"{run.stem}_export.{fmt}"))
    colors = None
    if args.bake == "views":
        scene_arg = args.scene or info.get("scene")
        if not scene_arg:
            raise ExportError("--bake views: the run names no scene; give --scene")
        from .mesh_renderer import MeshRenderer
        scene = load_scene_arg(scene_arg, int(info.get("downscale") or 1) if not args.scene else 1)
        mr = MeshRenderer(args.adapter)
        t0 = time.perf_counter()
        colors, seen = bake_views(model, scene, mesh_renderer=mr)
        print(f"baked colours from {len(scene.train_indices or scene.cameras)} training views on {mr.adapter_name} "
              f"in {time.perf_counter() - t0:.1f}s ({100 * np.mean(seen > 0):.1f}% of vertices seen; the others keep "
              f"SH DC)")
    export(model, out, fmt=fmt, colors=colors, y_up=args.y_up)
    print(f"{info.get('from', 'model')}: {model.num_vertices} vertices, {model.num_triangles} triangles, SH "
          f"{model.sh_size} coefficients")
    print(connectivity_line(connectivity(model.triangles, model.num_vertices)))
    print(f"wrote {out} ({fmt}, {out.stat().st_size} bytes{', y up' if args.y_up else ''}, colour from "
          f"{'training views' if args.bake == 'views' else 'SH DC'})")
    return 0


# ----------------------------------------------------------------------------- metrics

def psnr(a, b):
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return float("inf") if mse == 0 else -10.0 * np.log10(mse)


def ssim(a, b):
    from .train.losses import ssim_map_reference
    return float(ssim_map_reference(a, b).mean())


def heat(err, vmax=None):
    """[H, W] error -> [H, W, 3] heat map (black, red, yellow, white), scaled to ``vmax``
    (default: the 99th percentile, at least 1e-3)."""
    vmax = max(float(np.percentile(err, 99)) if err.size else 1.0, 1e-3) if vmax is None else vmax
    t = np.clip(err / vmax, 0.0, 1.0)[..., None]
    return np.clip(np.concatenate([3 * t, 3 * t - 1, 3 * t - 2], axis=-1), 0.0, 1.0)


def evaluate_mesh(model, scene, views, mesh_renderer, supersample=4, splat_renderer=None, out=None, images=4,
                  background=(0.0, 0.0, 0.0), interpolation="perspective"):
    """Per-view PSNR/SSIM of ``model`` (opaque, vertex colours) drawn by the mesh renderer,
    with the splatting renderer's PSNR at sigma 1e-4 / opacity 1 beside it when given.
    Writes ``view_XXX.png`` (ground truth | render | error heat map) for the first ``images``
    views to ``out``. Returns a list of per-view dicts."""
    from .cli import atomic_write_image
    from .types import TriangleModel
    rows = []
    opaque = TriangleModel(model.positions, model.triangles, model.sh, np.ones(model.num_vertices))
    for n, v in enumerate(views):
        cam, gt = scene.cameras[v], scene.images[v]
        t0 = time.perf_counter()
        img = mesh_renderer.render(model, cam, supersample=supersample, background=background,
                                   interpolation=interpolation).image
        ms = 1e3 * (time.perf_counter() - t0)
        row = dict(view=int(v), name=str(scene.image_names[v]) if scene.image_names else str(v),
                   psnr=psnr(img, gt), ssim=ssim(img, gt), render_ms=ms)
        if splat_renderer is not None and model.num_triangles:
            simg = splat_renderer.forward(opaque, cam, SIGMA_OPAQUE, background=background).image
            row["splat_psnr"] = psnr(simg, gt)
        rows.append(row)
        if out is not None and n < images:
            err = np.abs(np.asarray(img, np.float64) - gt).mean(-1)
            atomic_write_image(Path(out) / f"view_{v:03d}.png", np.concatenate([gt, img, heat(err)], axis=1))
    return rows


def _table(rows, has_splat):
    head = f"{'view':>6}  {'name':<24}{'PSNR':>8}{'SSIM':>8}" + (f"{'splat PSNR':>12}" if has_splat else "")
    lines = [head]
    for r in rows:
        lines.append(f"{r['view']:>6}  {r['name'][:23]:<24}{r['psnr']:>8.2f}{r['ssim']:>8.3f}"
                     + (f"{r.get('splat_psnr', float('nan')):>12.2f}" if has_splat else ""))
    if rows:
        mp = np.mean([r["psnr"] for r in rows])
        ms = np.mean([r["ssim"] for r in rows])
        extra = f"{np.mean([r['splat_psnr'] for r in rows]):>12.2f}" if has_splat else ""
        lines.append(f"{'mean':>6}  {'':<24}{mp:>8.2f}{ms:>8.3f}{extra}")
    return "\n".join(lines)


# ----------------------------------------------------------------------------- baseline

def poisson_baseline(scene, depth=8, workdir=None, trim_spacing=3.0):
    """A vertex-coloured mesh from the scene's SfM points through pycolmap's Poisson
    reconstruction. Normals: PCA of the 16 nearest points, oriented towards the nearest
    camera centre. Trimming: pycolmap's density trim removes everything on sparse clouds, so
    instead triangles with a vertex farther than ``trim_spacing`` x the points' median
    nearest-neighbour spacing from every point are deleted. Colours: the nearest point's
    colour. Returns a TriangleModel."""
    import tempfile

    import pycolmap
    from scipy.spatial import cKDTree

    from .export import SH_C0, read_mesh
    from .types import TriangleModel
    pts = None if scene.points is None else np.asarray(scene.points, np.float64)
    if pts is None or len(pts) < 16:
        raise ExportError(f"--baseline poisson: the scene has {0 if pts is None else len(pts)} points; need >= 16")
    cols = (np.asarray(scene.point_colors, np.float64) if scene.point_colors is not None
            else np.full((len(pts), 3), 0.5))
    tree = cKDTree(pts)
    _, nn = tree.query(pts, k=16)
    nb = pts[nn] - pts[nn].mean(1, keepdims=True)
    _, _, vt = np.linalg.svd(nb, full_matrices=False)
    normals = vt[:, -1, :]
    centres = np.stack([c.center for c in scene.cameras])
    _, ci = cKDTree(centres).query(pts)
    flip = np.einsum("ij,ij->i", normals, centres[ci] - pts) < 0
    normals[flip] *= -1
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        src, dst = Path(tmp) / "points.ply", Path(tmp) / "poisson.ply"
        dt = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4"),
                       ("red", "u1"), ("green", "u1"), ("blue", "u1")])
        arr = np.zeros(len(pts), dt)
        for i, k in enumerate("xyz"):
            arr[k] = pts[:, i]
            arr["n" + k] = normals[:, i]
        c8 = np.round(np.clip(cols, 0, 1) * 255).astype(np.uint8)
        arr["red"], arr["green"], arr["blue"] = c8[:, 0], c8[:, 1], c8[:, 2]
        header = ("ply\nformat binary_little_endian 1.0\nelement vertex %d\n" % len(pts)
                  + "".join(f"property float {k}\n" for k in ("x", "y", "z", "nx", "ny", "nz"))
                  + "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n")
        src.write_bytes(header.encode() + arr.tobytes())
        opts = pycolmap.PoissonMeshingOptions()
        opts.depth = int(depth)
        opts.trim = 0.0
        opts.color = True
        opts.num_threads = min(4, os.cpu_count() or 1)
        pycolmap.poisson_meshing(str(src), str(dst), opts)
        if not dst.is_file():
            raise ExportError("--baseline poisson: Poisson reconstruction produced no mesh")
        mesh = read_mesh(dst)
    dist, nearest = tree.query(mesh.positions)
    spacing = float(np.median(tree.query(pts, k=2)[0][:, 1]))
    far = dist > trim_spacing * spacing
    tri = mesh.triangles[~far[mesh.triangles].any(axis=1)]
    used = np.zeros(mesh.num_vertices, bool)
    used[tri.ravel()] = True
    new_from_old = np.cumsum(used) - 1
    col = cols[nearest[used]]
    return TriangleModel(mesh.positions[used], new_from_old[tri], ((col - 0.5) / SH_C0)[:, None, :],
                         np.ones(int(used.sum())))


# ----------------------------------------------------------------------------- eval command

def _normal_error(model, scene, views, folder, renderer_or_ctx):
    """Mean normal error of ``model`` (opaque) against the maps in ``folder`` on ``views``."""
    from .data.normals import load_normal_maps
    from .renderer import Renderer
    from .train.normals import NormalLoss, normal_error, render_normals
    maps = load_normal_maps(scene, folder, views=views)
    for w in maps.warnings:
        print(f"warning: {w}")
    r = renderer_or_ctx if isinstance(renderer_or_ctx, Renderer) else Renderer(renderer_or_ctx)
    k = NormalLoss(r)
    per = {}
    for v in views:
        if maps.maps[v] is not None:
            per[int(v)] = normal_error(render_normals(r, model, scene.cameras[v], 1e-4, loss=k), *maps.maps[v])
    if not per:
        print(f"normal error: no normal map in {folder} for the {len(views)} evaluated views")
        return dict(views=0)
    out = dict(views=len(per), folder=str(folder), loss=float(np.mean([e["loss"] for e in per.values()])),
               angle_deg=float(np.mean([e["angle_deg"] for e in per.values()])), per_view=per)
    print(f"normal error vs {folder} on {len(per)} of {len(views)} views: mean 1 - <N, P> {out['loss']:.4f}, "
          f"mean angle {out['angle_deg']:.2f} deg")
    return out


def run_eval(args):
    from .cli import UserError
    from .mesh_renderer import MeshRenderer
    if args.supersample < 1:
        raise ValueError(f"--supersample: expected an integer >= 1, got {args.supersample}")
    if args.baseline:
        if len(args.inputs) != 1:
            raise UserError("eval --baseline poisson: give only SCENE")
        scene_arg, run_arg = args.inputs[0], None
    else:
        if len(args.inputs) != 2:
            raise UserError("eval: expected RUN_OR_MESH SCENE (or --baseline poisson SCENE)")
        run_arg, scene_arg = args.inputs
    t0 = time.perf_counter()
    if run_arg is not None:
        model, info = load_run(run_arg)
        source = info.get("from")
    scene = load_scene_arg(scene_arg, args.downscale)
    if args.baseline:
        tb = time.perf_counter()
        model = poisson_baseline(scene, depth=args.poisson_depth)
        source = f"Poisson reconstruction of {len(scene.points)} SfM points (depth {args.poisson_depth}) " \
                 f"in {time.perf_counter() - tb:.1f}s"
    # the exported mesh is drawn with its vertex colours: the SH DC term (view-independent), opaque
    from .types import TriangleModel
    model = TriangleModel(model.positions, model.triangles, model.sh[:, :1], np.ones(model.num_vertices))
    if model.num_triangles == 0:
        raise ExportError(f"{run_arg or 'baseline'}: the mesh has no triangles; nothing to evaluate")
    if args.views == "test":
        views = list(scene.test_indices) or list(scene.train_indices)
    elif args.views == "train":
        views = list(scene.train_indices)
    else:
        views = list(range(len(scene.cameras)))
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
    splat = None
    mr = MeshRenderer(args.adapter)
    if not args.no_splat:
        from .renderer import Renderer
        splat = Renderer(mr.ctx)
    conn = connectivity(model.triangles, model.num_vertices)
    print(f"adapter: {mr.adapter_name}")
    print(f"mesh: {source}: {model.num_vertices} vertices, {model.num_triangles} triangles")
    print(connectivity_line(conn))
    print(f"scene: {scene_arg}: {len(views)} {'held-out' if args.views == 'test' and scene.test_indices else args.views}"
          f" views, {scene.cameras[0].width}x{scene.cameras[0].height}, supersampling {args.supersample}x"
          f"{args.supersample}")
    bg = tuple(float(x) for x in scene.background)
    rows = evaluate_mesh(model, scene, views, mr, args.supersample, splat, out, args.images, bg, args.interpolation)
    print(_table(rows, splat is not None))
    res = dict(mesh=str(run_arg) if run_arg else "baseline:poisson", source=source, scene=scene_arg,
               adapter=mr.adapter_name, supersample=args.supersample, interpolation=args.interpolation, views=rows,
               mean_psnr=float(np.mean([r["psnr"] for r in rows])), mean_ssim=float(np.mean([r["ssim"] for r in rows])),
               connectivity=conn, seconds=time.perf_counter() - t0)
    if splat is not None:
        res["mean_splat_psnr"] = float(np.mean([r["splat_psnr"] for r in rows]))
        res["splat_note"] = "trainer renderer at sigma 1e-4, opacity 1, no supersampling"
    if getattr(args, "normals", None):
        res["normal_error"] = _normal_error(model, scene, views, args.normals, splat or mr.ctx)
    tmp = out / f".metrics.json.tmp{os.getpid()}"
    tmp.write_text(json.dumps(res, indent=2) + "\n")
    os.replace(tmp, out / "metrics.json")
    print(f"mean render {np.mean([r['render_ms'] for r in rows]):.1f} ms/view; wrote {out}/metrics.json and "
          f"view_*.png (ground truth | render | error)")
    return 0
