"""Random test scenes: overlapping, tilted sheets of triangles that share vertices."""

import os

import numpy as np
from scipy.spatial import Delaunay

from tsplus_wgpu import Camera, TriangleModel


def look_at_camera(width, height, fov_deg=60.0, eye=(0.0, 0.0, -4.0), target=(0.0, 0.0, 0.0)):
    eye = np.asarray(eye, float)
    fwd = np.asarray(target, float) - eye
    fwd /= np.linalg.norm(fwd)
    up = np.array([0.0, -1.0, 0.0])
    right = np.cross(fwd, up)
    if np.linalg.norm(right) < 1e-9:
        right = np.array([1.0, 0.0, 0.0])
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    R = np.stack([right, down, fwd])
    m = np.eye(4)
    m[:3, :3] = R
    m[:3, 3] = -R @ eye
    f = 0.5 * width / np.tan(np.radians(fov_deg) / 2)
    return Camera(width, height, f, f, width / 2, height / 2, m)


def random_scene(seed, width, height, sheets=3, points_per_sheet=8, sh_k=4, opacity=(0.3, 0.95),
                 spread=1.3, degenerate_ok=False):
    """A few tilted sheets (Delaunay of random points) at different depths, overlapping
    on screen and extending partly outside the image."""
    rng = np.random.default_rng(seed)
    cam = look_at_camera(width, height)
    positions, triangles = [], []
    base = 0
    for s in range(sheets):
        pts2 = rng.uniform(-spread, spread, size=(points_per_sheet, 2))
        tri = Delaunay(pts2).simplices
        depth = rng.uniform(-1.0, 1.5)
        tilt = rng.normal(scale=0.3, size=2)
        z = depth + pts2 @ tilt + rng.normal(scale=0.05, size=points_per_sheet)
        positions.append(np.column_stack([pts2, z]))
        triangles.append(tri + base)
        base += points_per_sheet
    pos = np.concatenate(positions)
    tri = np.concatenate(triangles)
    n = pos.shape[0]
    sh = rng.normal(scale=0.25, size=(n, sh_k, 3))
    sh[:, 0] = rng.uniform(-1.5, 1.5, size=(n, 3))
    op = rng.uniform(*opacity, size=n)
    return TriangleModel(pos, tri, sh, op), cam


def f32_exact(model, cam):
    """The same scene with every parameter rounded to float32, so that a float32 kernel
    and the float64 twin start from identical numbers."""
    r = lambda a: np.asarray(a, np.float64).astype(np.float32).astype(np.float64)
    m = TriangleModel(r(model.positions), model.triangles, r(model.sh), r(model.opacity))
    c = Camera(cam.width, cam.height, float(np.float32(cam.fx)), float(np.float32(cam.fy)),
               float(np.float32(cam.cx)), float(np.float32(cam.cy)), r(cam.world_to_camera))
    return m, c


def submit(ctx, record):
    """Record with ``record(encoder)`` and submit (one kernel's dispatch in a test)."""
    enc = ctx.device.create_command_encoder()
    record(enc)
    ctx.queue.submit([enc.finish()])


def rel_error(a, b):
    """max |a - b| relative to max |b|."""
    b = np.asarray(b, np.float64)
    return float(np.abs(np.asarray(a, np.float64) - b).max() / max(np.abs(b).max(), 1e-300))


def similar_scene(scene, scale, shift):
    """``scene`` in another world: every length multiplied by ``scale``, then shifted by ``shift``
    (cameras, points, ground-truth mesh, depth maps; the images are the same). Returns
    ``(copy, sim)`` with ``sim`` the :class:`WorldFrame` whose ``to_frame`` maps the scene's world
    points to the copy's."""
    from tsplus_wgpu.data import WorldFrame
    sim = WorldFrame(scale, tuple(-np.asarray(shift, np.float64) / scale))
    return scene.in_frame(sim), sim


def child_env(repo, **extra):
    """``os.environ`` for a child ``python -m tsplus_wgpu...``: ``repo`` ahead of the caller's own
    ``PYTHONPATH`` (which may be where wgpu and the other packages are), plus ``extra``."""
    path = os.pathsep.join(p for p in (str(repo), os.environ.get("PYTHONPATH", "")) if p)
    return dict(os.environ, **extra, PYTHONPATH=path)


def merge_meshes(*parts):
    """One ``(vertices, faces)`` of several, each part's faces moved past the vertices before it."""
    vs, fs, off = [], [], 0
    for pv, pf in parts:
        vs.append(np.asarray(pv))
        fs.append(np.asarray(pf) + off)
        off += len(pv)
    return np.concatenate(vs), np.concatenate(fs)


def write_colmap_scene(root, views=4, images="pics", missing=(), points=50, size="tiny"):
    """A COLMAP text scene of ``procedural:<size>``'s first ``views`` views, the images in
    ``root/<images>`` (``missing``: views whose image is left out) and its first ``points`` points."""
    from pathlib import Path
    from scipy.spatial.transform import Rotation
    from tsplus_wgpu.data.procedural import load_procedural
    from tsplus_wgpu.io.atomic import write_image
    sc = load_procedural(size)
    root = Path(root)
    sparse = root / "sparse" / "0"
    sparse.mkdir(parents=True)
    (root / images).mkdir()
    c0 = sc.cameras[0]
    (sparse / "cameras.txt").write_text(f"1 PINHOLE {c0.width} {c0.height} {c0.fx} {c0.fy} {c0.cx} {c0.cy}\n")
    lines = []
    for i, c in enumerate(sc.cameras[:views]):
        x, y, z, w = Rotation.from_matrix(c.world_to_camera[:3, :3]).as_quat()
        t = c.world_to_camera[:3, 3]
        lines += [f"{i + 1} {w} {x} {y} {z} {t[0]} {t[1]} {t[2]} 1 view_{i:02d}.png", ""]
        if i not in missing:
            write_image(root / images / f"view_{i:02d}.png", sc.images[i])
    (sparse / "images.txt").write_text("\n".join(lines) + "\n")
    (sparse / "points3D.txt").write_text("".join(
        f"{k + 1} {p[0]} {p[1]} {p[2]} {int(c[0] * 255)} {int(c[1] * 255)} {int(c[2] * 255)} 0.5\n"
        for k, (p, c) in enumerate(zip(sc.points[:points], sc.point_colors[:points]))))
    return root
