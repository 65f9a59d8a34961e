"""``tsplus select``: extract an object from a run's mesh with 2D masks and remove it."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..apps.select import find_masks, read_mask, select_triangles, split_model
from ..errors import UserError
from ..io.atomic import write_json
from ..apps.runs import load_run
from ..io.export import export
from .scenes import add_images_arg, load_cli_scene, scene_warnings


def add_parser(sub):
    p = sub.add_parser(
        "select", help="extract an object from a run's mesh with 2D masks (object.ply/glb) and remove it "
                       "(scene_without_object.ply/glb)",
        description="For every view of the run's scene that has a mask in --masks (an image named like the view: "
                    "same stem, png/jpg; non-zero = object), render the triangle-ID buffer of the run's opaque mesh "
                    "from that view and collect the triangles under the mask; keep the triangles selected in at "
                    "least --vote of the views that see them (own a pixel in their ID buffer). Writes object.ply / "
                    "object.glb (the kept triangles) and scene_without_object.ply / .glb (the rest), unused vertices "
                    "dropped, atomically, plus selection.json. Views without a mask are skipped and counted.")
    p.add_argument("run", help="run folder (what tsplus train writes: mesh.ply, checkpoint.npz, config.json) or a "
                               "mesh file (.ply/.glb/.obj) or checkpoint .npz")
    p.add_argument("--masks", required=True, metavar="DIR", help="folder of mask images named like the views")
    p.add_argument("--vote", type=float, default=0.5,
                   help="keep a triangle when it is under the mask in at least this fraction of the views that "
                        "see it (default 0.5)")
    p.add_argument("--out", default=None, metavar="DIR",
                   help="output folder (default: the run folder, or the mesh file's folder)")
    p.add_argument("--scene", default=None,
                   help="scene whose cameras and view names to use (default: the one the run folder records; "
                        "needed for a mesh file)")
    add_images_arg(p, help="image folder inside the scene (default: the run's, else images)")
    p.add_argument("--adapter", default=None, help="GPU adapter to use (substring of its name)")
    return p


def _write_parts(out, model, info, scene, parts):
    """Each part as PLY and GLB with the run's own vertex colours (what ``tsplus export`` writes;
    SH DC where the mesh has none); the GLB +Y up on the scene's cameras (glTF's convention, as
    ``tsplus export`` writes a GLB), the PLY in the world's frame. Returns the paths written."""
    from ..data.upright import engine_rotation, scene_upright
    colors = info.get("colors")
    colors = colors if colors is not None and len(colors) == model.num_vertices else None
    up = scene_upright(scene)
    rot = None if up is None else engine_rotation(up)
    written = []
    for (stem, part), mask in parts:
        if part.num_triangles == 0:
            print(f"note: {stem} has no triangles; not written")
            continue
        col = None if colors is None else np.asarray(colors)[np.unique(model.triangles[mask])]   # submesh's order
        for fmt in ("ply", "glb"):
            written.append(export(part, out / f"{stem}.{fmt}", fmt, colors=col, rotation=rot if fmt == "glb" else None))
    if rot is not None and written:
        print("GLB files +Y up on the cameras' up (glTF's convention), PLY files in the world's frame")
    return written


def run(args):
    from ..render.renderer import Renderer
    mask_dir = Path(args.masks)
    if not mask_dir.is_dir():
        raise UserError(f"--masks {mask_dir}: no such folder; give the folder of mask images named like the views")
    if not 0.0 < args.vote <= 1.0:
        raise UserError(f"--vote: expected a fraction in (0, 1], got {args.vote:g}")
    run = Path(args.run)
    if not run.exists():
        raise UserError(f"{run}: no such run folder or mesh file")
    model, info = load_run(run)
    if model.num_triangles == 0:
        raise UserError(f"{run}: the mesh has no triangles")
    scene_arg = args.scene or info.get("scene")
    if not scene_arg:
        raise UserError(f"{run}: no scene recorded (config.json); pass --scene SCENE to name the views' scene")
    out = Path(args.out) if args.out else (run if run.is_dir() else run.parent)
    if out.exists() and not out.is_dir():
        raise UserError(f"--out {out}: exists and is not a folder")
    images = args.images or (None if args.scene else info.get("images"))
    scene = load_cli_scene(scene_arg, int(info.get("downscale") or 1), 0, images)     # prints its warnings
    paths = find_masks(mask_dir, scene.image_names)
    missing = [name for name, p in zip(scene.image_names, paths) if p is None]
    if len(missing) == len(paths):
        example = Path(scene.image_names[0]).with_suffix(".png").name if scene.image_names else "VIEW.png"
        raise UserError(f"--masks {mask_dir}: no mask matches a view of {scene_arg} (expected files named like the "
                        f"views, e.g. {example}); nothing to select")
    masks = [None if p is None else read_mask(p, cam.width, cam.height) for p, cam in zip(paths, scene.cameras)]
    renderer = Renderer(args.adapter)
    sel = select_triangles(model, scene.cameras, masks, vote=args.vote, renderer=renderer,
                           near=scene.frame().near_world())
    obj, rest = split_model(model, sel.keep)
    print(f"adapter: {renderer.adapter_name}")
    print(f"mesh: {model.num_vertices} vertices / {model.num_triangles} triangles ({info.get('from')}); scene "
          f"{scene_arg}: {len(scene.cameras)} views")
    print(f"views used: {len(sel.views)} with a mask; masks missing: {len(missing)}"
          + (f" ({', '.join(missing[:5])}{', ...' if len(missing) > 5 else ''})" if missing else ""))
    print(f"triangles: {int((sel.visible > 0).sum())} visible, {sel.num_selected} selected under a mask in at least "
          f"one view, {sel.num_kept} kept (under the mask in >= {args.vote:g} of the views that see them) -> "
          f"object; {sel.num_kept} removed, {rest.num_triangles} remain")
    if sel.num_kept == 0:
        raise UserError(f"--masks {mask_dir}: no triangle is under the masks in >= {args.vote:g} of the views that "
                        f"see it; check the masks (non-zero = object) or lower --vote")
    out.mkdir(parents=True, exist_ok=True)
    keep = np.asarray(sel.keep, bool)
    written = _write_parts(out, model, info, scene, ((("object", obj), keep), (("scene_without_object", rest), ~keep)))
    report = dict(run=str(run), scene=str(scene_arg), masks=str(mask_dir), vote=args.vote,
                  views_used=[scene.image_names[i] for i in sel.views], masks_missing=missing,
                  triangles=model.num_triangles, visible=int((sel.visible > 0).sum()), selected=sel.num_selected,
                  kept=sel.num_kept, removed=sel.num_kept, remaining=rest.num_triangles,
                  object_vertices=obj.num_vertices, remaining_vertices=rest.num_vertices,
                  files=[str(p) for p in written], scene_warnings=scene_warnings(scene))
    write_json(out / "selection.json", report)
    print("wrote " + ", ".join(str(p) for p in written) + f", {out / 'selection.json'}")
    return 0
