"""Object extraction and removal from 2D masks (``tsplus select``).

Opaque triangles make this direct: each pixel of a view belongs to one triangle (the
triangle-ID buffer of :meth:`Renderer.forward`, ``triangle_ids=True``), so a mask over a
view selects a set of triangles. Over all views with a mask, a triangle is kept when it is
under the mask in at least ``vote`` of the views that see it (own at least one pixel of
their ID buffer). The kept triangles are the object; the rest is the scene without it.

API::

    sel = select_triangles(model, cameras, masks, vote=0.5)    # masks: [H, W] bool or None per camera
    obj, rest = split_model(model, sel.keep)                    # unused vertices dropped, indices compacted

The ``tsplus select`` command is :mod:`tsplus_wgpu.cli.select`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..data.frame import WorldFrame
from ..errors import UserError
from ..types import TriangleModel

#: sigma of the ID render: nearly hard triangles, as the exported opaque mesh is drawn
ID_SIGMA = 1e-4
MASK_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")
OUTPUTS = ("object.ply", "object.glb", "scene_without_object.ply", "scene_without_object.glb")


@dataclass
class Selection:
    """Result of :func:`select_triangles`.

    Attributes:
        keep: ``[M]`` bool, the object's triangles (selected in >= ``vote`` of the views that see them).
        selected: ``[M]`` int, views in which the triangle owns a pixel under the mask.
        visible: ``[M]`` int, views (with a mask) in which the triangle owns at least one pixel.
        views: indices of the cameras that had a mask.
        vote: the threshold used.
    """

    keep: np.ndarray
    selected: np.ndarray
    visible: np.ndarray
    views: list = field(default_factory=list)
    vote: float = 0.5

    @property
    def num_selected(self):
        """Triangles under a mask in at least one view."""
        return int((self.selected > 0).sum())

    @property
    def num_kept(self):
        return int(self.keep.sum())


def opaque_model(model: TriangleModel) -> TriangleModel:
    """The model as the exported mesh is drawn: opacity 1 everywhere, SH DC only."""
    return TriangleModel(model.positions, model.triangles, model.sh[:, :1], np.ones(model.num_vertices))


def triangle_votes(model: TriangleModel, cameras, masks, renderer=None, sigma=ID_SIGMA, near=None):
    """Per triangle, the number of views where it is under the mask and where it is visible.

    Args:
        model: the mesh (drawn opaque, see :func:`opaque_model`).
        cameras: one :class:`Camera` per view.
        masks: per camera ``[H, W]`` bool (True = object) at the camera's size, or None to skip the view.
        renderer: a :class:`Renderer` (default: a new one).
        near: near plane in world units (default: the training default relative to the cameras'
            radius, :meth:`WorldFrame.near_world <tsplus_wgpu.data.frame.WorldFrame.near_world>`).

    Returns:
        ``(selected [M] int64, visible [M] int64, views list)``.
    """
    from ..render.renderer import Renderer
    if len(masks) != len(cameras):
        raise ValueError(f"masks: expected one per camera ({len(cameras)}), got {len(masks)}")
    r = renderer or Renderer()
    near = WorldFrame.for_cameras(cameras).near_world() if near is None else near
    m = model.num_triangles
    from ..render.device_model import DeviceModel
    opaque = DeviceModel.from_model(r, opaque_model(model))      # uploaded once for every view
    selected = np.zeros(m, np.int64)
    visible = np.zeros(m, np.int64)
    views = []
    for i, (cam, mask) in enumerate(zip(cameras, masks)):
        if mask is None:
            continue
        mask = np.asarray(mask)
        if mask.shape != (cam.height, cam.width):
            raise ValueError(f"masks[{i}]: shape {mask.shape} does not match the camera's {cam.height}x{cam.width}")
        ids = r.forward(opaque, cam, sigma, near=near, triangle_ids=True).triangle_ids
        drawn = ids >= 0
        visible[np.unique(ids[drawn])] += 1
        selected[np.unique(ids[drawn & mask.astype(bool)])] += 1
        views.append(i)
    return selected, visible, views


def select_triangles(model: TriangleModel, cameras, masks, vote=0.5, renderer=None, sigma=ID_SIGMA, near=None):
    """Triangles of ``model`` under the masks: kept when selected in at least ``vote`` (0 < vote
    <= 1) of the views that see them, and in one view at least. Returns a :class:`Selection`."""
    vote = float(vote)
    if not 0.0 < vote <= 1.0:
        raise ValueError(f"--vote: expected a fraction in (0, 1], got {vote:g}")
    selected, visible, views = triangle_votes(model, cameras, masks, renderer, sigma, near)
    keep = (selected > 0) & (selected >= vote * visible - 1e-9)
    return Selection(keep=keep, selected=selected, visible=visible, views=views, vote=vote)


def submesh(model: TriangleModel, tri_mask) -> TriangleModel:
    """The triangles where ``tri_mask`` is True, with unused vertices dropped and indices compacted
    (vertex order kept)."""
    tri = model.triangles[np.asarray(tri_mask, bool)]
    used = np.zeros(model.num_vertices, bool)
    used[tri.ravel()] = True
    new_index = np.cumsum(used) - 1
    return TriangleModel(model.positions[used], new_index[tri].reshape(-1, 3), model.sh[used], model.opacity[used])


def split_model(model: TriangleModel, keep):
    """``(object, rest)``: the kept triangles and the others, each a compact model."""
    keep = np.asarray(keep, bool)
    return submesh(model, keep), submesh(model, ~keep)


# ----------------------------------------------------------------------------- masks on disk

def _is_lossy(path):
    return Path(path).suffix.lower() in (".jpg", ".jpeg", ".webp")


def read_mask(path, width, height):
    """``[height, width]`` bool mask from an image file: non-zero = object (any of R, G, B; the
    alpha channel when the colour is black everywhere; JPEG/WebP: >= 128, since lossy compression
    leaves faint non-zero pixels). A mask an integer factor larger than the view is reduced by
    block majority."""
    import imageio.v3 as iio
    try:
        img = np.asarray(iio.imread(path))
    except Exception as exc:
        why = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:120]
        raise UserError(f"--masks: {path}: cannot read the image ({why}); "
                        f"replace it with a PNG mask (non-zero = object) or remove it") from None
    if img.ndim == 3:
        if img.shape[2] == 4 and not np.any(img[..., :3]):
            img = img[..., 3]
        else:
            img = img[..., :3].max(axis=2) if img.shape[2] >= 3 else img[..., 0]
    if img.ndim != 2:
        raise UserError(f"--masks: {path}: expected a 2-D image, got shape {img.shape}")
    thr = 128 if _is_lossy(path) and img.dtype == np.uint8 else 0
    mask = img > thr
    h, w = mask.shape
    if (h, w) != (height, width):
        fy, fx = h // height, w // width
        if fy == fx and fy >= 1 and h == fy * height and w == fx * width:
            mask = mask.reshape(height, fy, width, fx).mean(axis=(1, 3)) >= 0.5
        else:
            raise UserError(f"--masks: {path} is {w}x{h} but its view is {width}x{height}; give masks at the "
                            f"view's size (or an integer multiple of it)")
    return mask


def find_masks(mask_dir, image_names):
    """Per view, the mask file named like its image (same stem, any image extension; also
    under the same relative sub-folder), or None. Returns a list of paths / None."""
    mask_dir = Path(mask_dir)
    by_path, by_stem = {}, {}

    def better(old, new):   # PNG first when both exist, else the first in sorted order
        return old is None or (old.suffix.lower() != ".png" and new.suffix.lower() == ".png")

    for p in sorted(mask_dir.rglob("*")):
        if p.is_file() and p.suffix.lower() in MASK_EXTENSIONS:
            key = p.relative_to(mask_dir).with_suffix("").as_posix()
            if better(by_path.get(key), p):
                by_path[key] = p
            if better(by_stem.get(p.stem), p):
                by_stem[p.stem] = p
    out = []
    for name in image_names:
        rel = Path(name).with_suffix("")
        out.append(by_path.get(rel.as_posix()) or by_stem.get(rel.name))
    return out


# ----------------------------------------------------------------------------- measurement

def procedural_scores(model=None, size="small", objects=None, vote=0.5, renderer=None, scene=None):
    """Recall / precision of :func:`select_triangles` on the procedural scene with its own object
    masks. ``model``: None (the ground-truth mesh drawn opaque: every triangle knows its object)
    or a trained mesh, whose triangles take the object of the ground-truth face nearest to their
    centroid. Recall counts the object's triangles that own a pixel in at least one view.
    Returns a list of dicts (object, triangles, seen, kept, recall, precision, removed_left: the
    object's seen triangles left in the scene, mask_pixels)."""
    from ..data.procedural import demo_model, load_procedural
    from .collider import MeshCollider
    scene = scene or load_procedural(size)
    g = scene.gt_mesh
    if model is None:
        model, label = demo_model(0), g.face_object
    else:
        cen = model.positions[model.triangles].mean(axis=1)
        col = MeshCollider((g.vertices, g.faces), backend="numpy")
        _, dist, tri, _ = col.closest_points(cen, 10.0)
        label = np.where(tri >= 0, g.face_object[np.maximum(tri, 0)], -1)
    rows = []
    for name in objects or g.object_names:
        k = g.object_names.index(name)
        masks = [m == k for m in scene.masks]
        sel = select_triangles(model, scene.cameras, masks, vote, renderer)
        obj = label == k
        seen = obj & (sel.visible > 0)
        hit = int((sel.keep & obj).sum())
        rows.append(dict(object=name, triangles=int(obj.sum()), seen=int(seen.sum()), kept=sel.num_kept,
                         recall=hit / max(int(seen.sum()), 1), precision=hit / max(sel.num_kept, 1),
                         removed_left=int((seen & ~sel.keep).sum()), mask_pixels=int(sum(m.sum() for m in masks))))
    return rows


def _main(argv=None):
    import argparse
    import time
    p = argparse.ArgumentParser(prog="python -m tsplus_wgpu.apps.select",
                                description="Recall / precision of tsplus select on the procedural scene's objects "
                                            "(its own masks), for the ground-truth mesh or a trained run.")
    p.add_argument("--size", default="small", choices=["tiny", "small", "demo"])
    p.add_argument("--run", default=None, help="a trained run folder / mesh on procedural:SIZE (default: the "
                                                "ground-truth mesh)")
    p.add_argument("--vote", type=float, default=0.5)
    p.add_argument("--objects", nargs="*", default=None)
    args = p.parse_args(argv)
    from .runs import load_run
    from ..render.renderer import Renderer
    model = load_run(args.run)[0] if args.run else None
    r = Renderer()
    t0 = time.perf_counter()
    rows = procedural_scores(model, args.size, args.objects, args.vote, r)
    dt = time.perf_counter() - t0
    print(f"procedural:{args.size}, {'ground-truth mesh' if model is None else args.run}, vote {args.vote:g}, "
          f"{r.adapter_name}")
    print(f"{'object':<14}{'triangles':>10}{'seen':>7}{'kept':>7}{'recall':>9}{'precision':>11}{'left':>6}")
    for row in rows:
        print(f"{row['object']:<14}{row['triangles']:>10}{row['seen']:>7}{row['kept']:>7}{row['recall']:>9.3f}"
              f"{row['precision']:>11.3f}{row['removed_left']:>6}")
    used = [row for row in rows if row["seen"] and row["mask_pixels"]]
    rec = [row["recall"] for row in used]
    prec = [row["precision"] for row in used]
    print(f"mean recall {np.mean(rec):.3f} (min {np.min(rec):.3f}), mean precision {np.mean(prec):.3f} "
          f"(min {np.min(prec):.3f}) over the {len(used)} objects that some mask shows; {dt:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(_main())
