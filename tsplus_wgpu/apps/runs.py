"""Loading what ``tsplus train`` wrote: a run folder (``mesh.ply``, ``checkpoint.npz``,
``config.json``), a checkpoint, or any mesh file, as a :class:`~tsplus_wgpu.TriangleModel`.
Turning a checkpoint's logits into opacities needs the run's opacity-floor schedule, so this
lives above training; :mod:`tsplus_wgpu.io.export` (writing and reading mesh files) does not
depend on it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..io.export import ExportError, file_frame, read_mesh, read_ply, read_ply_colors
from ..types import TriangleModel


def checkpoint_model(path):
    """(TriangleModel with activated opacity, config dict) from a trainer checkpoint."""
    from ..train.schedules import Schedule
    try:
        with np.load(path) as z:
            arrays = {k: z[k] for k in z.files}
        meta = json.loads(bytes(arrays.pop("meta")).decode())
        cfg = meta["config"]
        sched = Schedule(total=int(cfg["iterations"]), indoor=bool(cfg.get("indoor")), quick=bool(cfg.get("quick")))
        floor = sched.opacity_floor(int(meta["iteration"]))
        logits = arrays["logits"].astype(np.float64)
        opacity = floor + (1.0 - floor) / (1.0 + np.exp(-logits))
        sh = arrays["sh_planar"].transpose(1, 0, 2)
        opacity = np.clip(opacity, 0.0, 1.0).astype(np.float32)   # float32 like every other parameter
        model = TriangleModel(arrays["positions"], arrays["triangles"], sh, opacity)
    except ExportError:
        raise
    except Exception as exc:
        raise ExportError(f"{path}: not a readable tsplus checkpoint ({exc})") from None
    return model, cfg


def load_run(path):
    """Load what ``tsplus train`` wrote, or a mesh file.

    ``path`` may be a run folder (its ``mesh.ply``, the cleaned opaque mesh, with the full SH
    and opacity of ``checkpoint.npz`` attached to the vertices they came from when the
    checkpoint is there), a PLY / GLB / OBJ file, or a ``checkpoint.npz`` (every triangle, no
    final cleanup). Returns ``(TriangleModel, info dict)`` with ``info['scene']`` the run's
    scene argument when known and ``info['colors']`` the PLY's own vertex colours (what an
    engine draws: ``tsplus train`` fits them to the photos) when it has them."""
    path = Path(path)
    if not path.exists():
        raise ExportError(f"{path}: no such run folder or mesh file")
    info = {"source": str(path)}
    if path.is_dir():
        cfg_path = path / "config.json"
        if cfg_path.is_file():
            try:
                cfg = json.loads(cfg_path.read_text())
                info["scene"] = cfg.get("extra", {}).get("scene")
                info["downscale"] = cfg.get("extra", {}).get("downscale", 1)
                info["images"] = cfg.get("extra", {}).get("images")
                info["background"] = cfg.get("background")
            except Exception:
                pass
        try:                                    # the cameras' up, as `tsplus train` recorded it
            info["upright"] = json.loads((path / "metrics.json").read_text()).get("upright")
        except (OSError, ValueError, AttributeError):
            pass
        mesh_path, ckpt = path / "mesh.ply", path / "checkpoint.npz"
        if not mesh_path.is_file():
            if ckpt.is_file():
                model, _ = checkpoint_model(ckpt)
                info["from"] = "checkpoint.npz (no mesh.ply: every triangle, no final cleanup)"
                return model, info
            raise ExportError(f"{path}: not a tsplus run (no mesh.ply or checkpoint.npz)")
        mesh = read_ply(mesh_path)
        info["from"] = "mesh.ply"
        info["colors"] = read_ply_colors(mesh_path)
        if ckpt.is_file():
            full, _ = checkpoint_model(ckpt)
            attached = _attach(mesh, full)
            if attached is not None:
                info["from"] = "mesh.ply with SH and opacity from checkpoint.npz"
                return attached, info
        return mesh, info
    suffix = path.suffix.lower()
    if suffix == ".npz":
        model, cfg = checkpoint_model(path)
        info["scene"] = cfg.get("extra", {}).get("scene")
        info["from"] = "checkpoint"
        return model, info
    if suffix == ".ply":
        info["from"] = "ply"
        info["colors"] = read_ply_colors(path)
        return _to_world(read_ply(path), path, info)
    if suffix in (".glb", ".gltf", ".obj", ".off", ".stl"):
        info["from"] = suffix[1:]
        return _to_world(read_mesh(path), path, info)
    raise ExportError(f"{path}: unknown file type {suffix or '(none)'}; expected a run folder, .ply, .glb, .obj "
                      f"or checkpoint .npz")


def _to_world(model: TriangleModel, path, info):
    """A mesh file `tsplus export --y-up` (or ``--origin`` / ``--scale``) wrote, taken back into
    the world it was exported from (its frame is recorded in it), with its +Y kept in ``info``
    (the viewer's up)."""
    frame = file_frame(path) if path.suffix.lower() in (".glb", ".obj", ".ply") else None
    if frame is not None:
        a, t = frame[:3, :3], frame[:3, 3]
        s2 = float(np.cbrt(np.linalg.det(a))) ** 2
        model = TriangleModel((model.positions - t) @ a / s2, model.triangles, model.sh, model.opacity)
        info["from"] += " (taken back into the world it was exported from)"
        up = a[1] / np.linalg.norm(a[1])
        fwd = -a[2] / np.linalg.norm(a[2])
        info["upright"] = {"up": up.tolist(), "forward": fwd.tolist(), "how": "the file's own frame"}
        info["file_up"] = up.tolist()
    return model, info


def _attach(mesh: TriangleModel, full: TriangleModel):
    """The cleaned mesh with SH and opacity of the checkpoint vertices at the same (float32)
    positions; vertices the checkpoint does not have (the backdrop that fills holes at export,
    train/final.py) keep the mesh's own colour as SH DC and opacity 1. None when fewer than
    half of the mesh's vertices are the checkpoint's (another model's mesh)."""
    key = lambda p: np.ascontiguousarray(p.astype(np.float32)).view(np.dtype((np.void, 12))).ravel()  # noqa: E731
    kf, km = key(full.positions), key(mesh.positions)
    if len(kf) == 0 or len(km) == 0:
        return None
    order = np.argsort(kf, kind="stable")
    pos = np.clip(np.searchsorted(kf[order], km), 0, len(kf) - 1)
    idx = order[pos]
    hit = kf[idx] == km
    if hit.mean() < 0.5:
        return None
    sh = np.zeros((mesh.num_vertices,) + full.sh.shape[1:])
    sh[hit] = full.sh[idx[hit]]
    sh[~hit, 0] = mesh.sh[~hit, 0]
    opacity = np.where(hit, full.opacity[idx], 1.0)
    positions = np.where(hit[:, None], full.positions[idx], mesh.positions)
    return TriangleModel(positions, mesh.triangles, sh, opacity)
