"""Mesh-based novel-view metrics (held-out views drawn by the depth-tested
:class:`~tsplus_wgpu.MeshRenderer`) with the splatting renderer's PSNR beside them, the normal
error against normal maps, and the Poisson baseline (``tsplus eval``: :mod:`tsplus_wgpu.cli.eval`)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..io.atomic import write_image
from ..io.export import ExportError, read_mesh
from ..io.metrics import psnr, ssim
from ..types import SH_C0, TriangleModel

SIGMA_OPAQUE = 1e-4


# ----------------------------------------------------------------------------- metrics

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
            write_image(Path(out) / f"view_{v:03d}.png", np.concatenate([gt, img, heat(err)], axis=1))
    return rows


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
        opts.num_threads = 1               # more threads give a different mesh from run to run
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


# ----------------------------------------------------------------------------- normal error

def normal_error_summary(model, scene, views, folder, renderer_or_ctx):
    """Mean normal error of ``model`` (opaque) against the maps in ``folder`` on ``views``."""
    from ..data.normals import load_normal_maps
    from ..render.renderer import Renderer
    from ..train.normals import NormalLoss, normal_error, render_normals
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


