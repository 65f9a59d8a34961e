"""Tiny scenes, meshes and the corruptions that tests/cli/test_fuzz.py applies to copies of them.

The scenes come from five views of the procedural scene (64x48): the same cameras, images and
points written as a COLMAP model (text and binary, written here byte by byte), a
``transforms.json`` scene and an LLFF scene. Everything is built in plain Python so that a
corruption can change exactly one field."""

from __future__ import annotations

import io
import json
import struct
from pathlib import Path

import numpy as np

VIEWS = 5
COLMAP_MODEL_IDS = {"SIMPLE_PINHOLE": 0, "PINHOLE": 1, "SIMPLE_RADIAL": 2, "OPENCV": 4}


# ----------------------------------------------------------------------------------- the views

def procedural_views(views=VIEWS, points=60):
    """``(cams, images, names, xyz, rgb)``: the first ``views`` views of ``procedural:tiny``
    (cameras, uint8 images) and ``points`` of its points with their colours (uint8)."""
    from tsplus_wgpu.data.procedural import load_procedural
    sc = load_procedural("tiny")
    cams = list(sc.cameras[:views])
    imgs = [np.round(np.clip(im, 0, 1) * 255).astype(np.uint8) for im in sc.images[:views]]
    names = list(sc.image_names[:views])
    rng = np.random.default_rng(0)
    pick = np.sort(rng.choice(len(sc.points), points, replace=False))
    xyz = np.asarray(sc.points[pick], np.float64)
    rgb = np.round(np.clip(sc.point_colors[pick], 0, 1) * 255).astype(np.uint8)
    return cams, imgs, names, xyz, rgb


def write_png(path, img):
    from PIL import Image
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(img).save(path)


def _quat_wxyz(R):
    from scipy.spatial.transform import Rotation
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return (w, x, y, z)


# ----------------------------------------------------------------------------------- COLMAP

def colmap_model(views):
    """The COLMAP model of ``views`` as plain data: ``{"cameras": [(id, model, w, h, params)],
    "images": [(id, qvec, tvec, cam_id, name, points2D [(x, y, pid)])], "points": [(pid, xyz, rgb,
    err, track [(image_id, idx)])]}``; a point is kept when at least two views see it."""
    cams, _, names, xyz, rgb = views
    c0 = cams[0]
    cameras = [(1, "PINHOLE", c0.width, c0.height, [c0.fx, c0.fy, c0.cx, c0.cy])]
    obs = {}                                     # point index -> [(image_id, (x, y))]
    for i, c in enumerate(cams):
        m = np.asarray(c.world_to_camera, np.float64)
        pc = xyz @ m[:3, :3].T + m[:3, 3]
        for p in range(len(xyz)):
            z = pc[p, 2]
            if z <= 1e-3:
                continue
            x, y = c.fx * pc[p, 0] / z + c.cx, c.fy * pc[p, 1] / z + c.cy
            if 0 <= x < c.width and 0 <= y < c.height:
                obs.setdefault(p, []).append((i + 1, (x, y)))
    kept = [p for p in sorted(obs) if len(obs[p]) >= 2]
    pts2d = {i + 1: [] for i in range(len(cams))}
    points = []
    for pid, p in enumerate(kept, 1):
        track = []
        for image_id, (x, y) in obs[p]:
            track.append((image_id, len(pts2d[image_id])))
            pts2d[image_id].append((x, y, pid))
        points.append((pid, xyz[p], rgb[p], 0.5, track))
    images = []
    for i, (c, name) in enumerate(zip(cams, names)):
        m = np.asarray(c.world_to_camera, np.float64)
        images.append((i + 1, _quat_wxyz(m[:3, :3]), tuple(m[:3, 3]), 1, name, pts2d[i + 1]))
    return {"cameras": cameras, "images": images, "points": points}


def write_colmap_text(d: Path, model):
    d.mkdir(parents=True, exist_ok=True)
    lines = ["# Camera list with one line of data per camera:"]
    lines += [f"{cid} {m} {w} {h} " + " ".join(repr(float(v)) for v in params)
              for cid, m, w, h, params in model["cameras"]]
    (d / "cameras.txt").write_text("\n".join(lines) + "\n")
    lines = ["# Image list with two lines of data per image:"]
    for iid, q, t, cid, name, p2 in model["images"]:
        lines.append(f"{iid} " + " ".join(repr(float(v)) for v in (*q, *t)) + f" {cid} {name}")
        lines.append(" ".join(f"{float(x)!r} {float(y)!r} {pid}" for x, y, pid in p2))
    (d / "images.txt").write_text("\n".join(lines) + "\n")
    lines = ["# 3D point list with one line of data per point:"]
    for pid, p, c, err, track in model["points"]:
        lines.append(f"{pid} " + " ".join(repr(float(v)) for v in p) + " " + " ".join(str(int(v)) for v in c)
                     + f" {err} " + " ".join(f"{a} {b}" for a, b in track))
    (d / "points3D.txt").write_text("\n".join(lines) + "\n")


def write_colmap_binary(d: Path, model, counts=None):
    """The binary model; ``counts`` may override the declared counts: ``{"cameras": n,
    "images": n, "points": n, "track": n (first point), "points2D": n (first image)}``."""
    counts = counts or {}
    d.mkdir(parents=True, exist_ok=True)
    b = io.BytesIO()
    b.write(struct.pack("<Q", counts.get("cameras", len(model["cameras"]))))
    for cid, m, w, h, params in model["cameras"]:
        b.write(struct.pack("<iiQQ", cid, COLMAP_MODEL_IDS.get(m, m if isinstance(m, int) else 99), w, h))
        b.write(struct.pack(f"<{len(params)}d", *params))
    (d / "cameras.bin").write_bytes(b.getvalue())
    b = io.BytesIO()
    b.write(struct.pack("<Q", counts.get("images", len(model["images"]))))
    for k, (iid, q, t, cid, name, p2) in enumerate(model["images"]):
        b.write(struct.pack("<I7dI", iid, *q, *t, cid))
        b.write(name.encode() + b"\0")
        b.write(struct.pack("<Q", counts.get("points2D", len(p2)) if k == 0 else len(p2)))
        for x, y, pid in p2:
            b.write(struct.pack("<ddQ", x, y, pid))
    (d / "images.bin").write_bytes(b.getvalue())
    b = io.BytesIO()
    b.write(struct.pack("<Q", counts.get("points", len(model["points"]))))
    for k, (pid, p, c, err, track) in enumerate(model["points"]):
        b.write(struct.pack("<Q3d3Bd", pid, *p, *c, err))
        b.write(struct.pack("<Q", counts.get("track", len(track)) if k == 0 else len(track)))
        for a, idx in track:
            b.write(struct.pack("<II", a, idx))
    (d / "points3D.bin").write_bytes(b.getvalue())


def edit_model(model, cameras=None, image=None, point=None):
    """A copy of ``model`` with camera 0's fields replaced (``cameras`` = dict of model/w/h/params),
    image ``image[0]``'s fields (``image = (k, dict of q/t/cid/name)``) or point ``point[0]``'s xyz."""
    out = {k: list(v) for k, v in model.items()}
    if cameras:
        cid, m, w, h, params = out["cameras"][0]
        out["cameras"][0] = (cid, cameras.get("model", m), cameras.get("w", w), cameras.get("h", h),
                             cameras.get("params", params))
    if image:
        k, f = image
        iid, q, t, cid, name, p2 = out["images"][k]
        out["images"][k] = (iid, f.get("q", q), f.get("t", t), f.get("cid", cid), f.get("name", name), p2)
    if point:
        k, xyz = point
        pid, _, c, err, track = out["points"][k]
        out["points"][k] = (pid, np.asarray(xyz, np.float64), c, err, track)
    return out


def make_colmap(root: Path, views, binary: bool):
    for name, img in zip(views[2], views[1]):
        write_png(root / "images" / name, img)
    model = colmap_model(views)
    (write_colmap_binary if binary else write_colmap_text)(root / "sparse" / "0", model)
    return model


# ----------------------------------------------------------------------------------- transforms.json / LLFF

def transforms_dict(views):
    cams, _, names, _, _ = views
    c0 = cams[0]
    frames = []
    for c, name in zip(cams, names):
        c2w = np.linalg.inv(np.asarray(c.world_to_camera, np.float64)) @ np.diag([1.0, -1.0, -1.0, 1.0])
        frames.append({"file_path": f"images/{Path(name).stem}", "transform_matrix": c2w.tolist()})
    return {"camera_angle_x": float(2 * np.arctan(0.5 * c0.width / c0.fx)), "frames": frames}


def make_transforms(root: Path, views):
    for name, img in zip(views[2], views[1]):
        write_png(root / "images" / name, img)
    (root / "transforms.json").write_text(json.dumps(transforms_dict(views), indent=1))


def llff_array(views):
    cams, _, _, _, _ = views
    rows = []
    for c in cams:
        c2w = np.linalg.inv(np.asarray(c.world_to_camera, np.float64))
        m = np.zeros((3, 5))
        m[:, 0], m[:, 1], m[:, 2], m[:, 3] = c2w[:3, 1], c2w[:3, 0], -c2w[:3, 2], c2w[:3, 3]
        m[:, 4] = (c.height, c.width, c.fx)
        rows.append(np.concatenate([m.ravel(), [0.5, 12.0]]))
    return np.array(rows)


def make_llff(root: Path, views):
    for name, img in zip(views[2], views[1]):
        write_png(root / "images" / name, img)
    np.save(root / "poses_bounds.npy", llff_array(views))


# ----------------------------------------------------------------------------------- meshes

def write_ply_ascii(path: Path, vertices, faces):
    lines = ["ply", "format ascii 1.0", f"element vertex {len(vertices)}", "property float x",
             "property float y", "property float z", f"element face {len(faces)}",
             "property list uchar int vertex_indices", "end_header"]
    lines += [" ".join(repr(float(v)) for v in p) for p in vertices]
    lines += ["3 " + " ".join(str(int(i)) for i in f) for f in faces]
    path.write_text("\n".join(lines) + "\n")


def write_obj(path: Path, vertices, faces):
    lines = ["v " + " ".join(repr(float(v)) for v in p) for p in vertices]
    lines += ["f " + " ".join(str(int(i) + 1) for i in f) for f in faces]
    path.write_text("\n".join(lines) + "\n")


TETRA_V = [(0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)]
TETRA_F = [(0, 1, 2), (0, 1, 3), (0, 2, 3), (1, 2, 3)]


# ----------------------------------------------------------------------------------- corruptions

def truncate(path: Path, keep=0.5):
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])


def garbage(path: Path, n=4096, seed=1):
    path.write_bytes(np.random.default_rng(seed).integers(0, 256, n, dtype=np.uint8).tobytes())


def edit_text(path: Path, old: str, new: str, count=1):
    text = path.read_text()
    assert old in text, (path, old)
    path.write_text(text.replace(old, new, count))


def edit_json(path: Path, fn):
    data = json.loads(path.read_text())
    fn(data)
    path.write_text(json.dumps(data))


def edit_npz(path: Path, fn):
    """Rewrite an .npz with ``fn(arrays)`` applied (it edits the dict in place)."""
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    fn(arrays)
    path.unlink()
    np.savez(path, **arrays)


def edit_meta(arrays, fn):
    meta = json.loads(bytes(arrays["meta"]).decode())
    fn(meta)
    arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
