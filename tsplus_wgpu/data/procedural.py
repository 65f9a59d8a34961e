"""The built-in procedural scene: a small textured room with furniture, rendered here.

Everything is deterministic for a given ``seed``: the layout (a floor, four walls, a
ceiling, a table, three boxes, a sphere and a vase), the procedural textures, the camera
path and the SfM-like points.  Images are rendered by :func:`~.raster.rasterize`, a vectorised
NumPy z-buffer rasteriser with near-plane clipping and perspective-correct interpolation
of the 3D surface point; the textures are evaluated at that 3D point, so every view is
consistent with every other and with the ground-truth mesh.  Shading is view-independent
(baked Lambert + a soft point light), as a diffuse scene would look to a camera.

World frame: metres, z up, floor at z = 0.  Cameras follow the project convention
(OpenCV: +z forward, y down, pixel centres at +0.5).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..types import Camera
from .raster import NEAR, rasterize
from .scene import GTMesh, Scene, make_split
from .tracks import from_mask

SIZES = {
    #        width, height, views, points, supersampling
    "tiny": (64, 48, 8, 3000, 3),
    "small": (160, 120, 24, 6000, 2),
    "demo": (320, 240, 40, 20000, 2),
}

ROOM = np.array([[-3.2, -2.6, 0.0], [3.2, 2.6, 2.6]])  # min, max corners
LIGHT_DIR = np.array([0.35, -0.25, 0.9]) / np.linalg.norm([0.35, -0.25, 0.9])
LAMP = np.array([0.5, 0.4, 2.45])


# --------------------------------------------------------------------------- geometry
@dataclass
class _Obj:
    name: str
    kind: str          # texture family
    color: np.ndarray  # base colour [3]
    color2: np.ndarray  # second colour [3]
    center: np.ndarray  # for texture coordinates


def _grid_quad(origin, du, dv, nu, nv):
    """Vertices and triangles of a planar grid origin + s*du + t*dv, s,t in [0,1]."""
    s, t = np.meshgrid(np.linspace(0, 1, nu + 1), np.linspace(0, 1, nv + 1), indexing="ij")
    v = origin + s.reshape(-1, 1) * du + t.reshape(-1, 1) * dv
    idx = np.arange((nu + 1) * (nv + 1)).reshape(nu + 1, nv + 1)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    f = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return v, f


def _box(center, size, yaw=0.0, n=1):
    """A closed box (each side an n x n grid), rotated by ``yaw`` about z."""
    hx, hy, hz = np.asarray(size, float) / 2
    verts, faces = [], []
    off = 0
    ex, ey, ez = np.eye(3)
    sides = [  # origin, du, dv
        (np.array([-hx, -hy, -hz]), 2 * hx * ex, 2 * hy * ey),
        (np.array([-hx, -hy, hz]), 2 * hx * ex, 2 * hy * ey),
        (np.array([-hx, -hy, -hz]), 2 * hx * ex, 2 * hz * ez),
        (np.array([-hx, hy, -hz]), 2 * hx * ex, 2 * hz * ez),
        (np.array([-hx, -hy, -hz]), 2 * hy * ey, 2 * hz * ez),
        (np.array([hx, -hy, -hz]), 2 * hy * ey, 2 * hz * ez),
    ]
    for o, du, dv in sides:
        v, f = _grid_quad(o, du, dv, n, n)
        verts.append(v)
        faces.append(f + off)
        off += len(v)
    v = np.concatenate(verts)
    c, s = math.cos(yaw), math.sin(yaw)
    Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    return v @ Rz.T + np.asarray(center, float), np.concatenate(faces)


def _icosphere(center, radius, subdiv=2):
    t = (1 + 5 ** 0.5) / 2
    v = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t],
                  [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], float)
    f = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
                  [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
                  [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]])
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    for _ in range(subdiv):
        edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        uniq, inv = np.unique(edges, axis=0, return_inverse=True)
        mid = v[uniq].mean(1)
        mid /= np.linalg.norm(mid, axis=1, keepdims=True)
        m = inv.reshape(3, -1).T + len(v)  # [F, 3] midpoints of edges 01, 12, 20
        v = np.concatenate([v, mid])
        a, b, c = f.T
        ab, bc, ca = m.T
        f = np.concatenate([np.stack([a, ab, ca], 1), np.stack([b, bc, ab], 1),
                            np.stack([c, ca, bc], 1), np.stack([ab, bc, ca], 1)])
    return v * radius + np.asarray(center, float), f


def _cylinder(center, radius, height, segments=20):
    ang = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    ring = np.stack([np.cos(ang), np.sin(ang)], 1) * radius
    bottom = np.concatenate([ring, np.zeros((segments, 1))], 1)
    top = np.concatenate([ring * 0.8, np.full((segments, 1), height)], 1)
    v = np.concatenate([bottom, top, [[0, 0, 0], [0, 0, height]]]) + np.asarray(center, float)
    i = np.arange(segments)
    j = (i + 1) % segments
    f = np.concatenate([np.stack([i, j, j + segments], 1), np.stack([i, j + segments, i + segments], 1),
                        np.stack([np.full(segments, 2 * segments), j, i], 1),
                        np.stack([np.full(segments, 2 * segments + 1), i + segments, j + segments], 1)])
    return v, f


def _orient(v, f, inside_point, outward=True):
    """Flip faces so their normal points away from (or, ``outward=False``, towards) ``inside_point``."""
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    c = v[f].mean(1)
    s = np.einsum("ij,ij->i", n, c - inside_point)
    flip = s < 0 if outward else s > 0
    f = f.copy()
    f[flip] = f[flip][:, [0, 2, 1]]
    return f


def build_world(seed: int = 0):
    """Build the room: returns ``(vertices [V,3], faces [F,3], face_object [F], objects list)``."""
    rng = np.random.default_rng(seed)
    jit = lambda s: rng.uniform(-s, s)  # noqa: E731
    lo, hi = ROOM
    room_c = (lo + hi) / 2
    parts = []  # (verts, faces, obj)

    def pal(base, spread=0.08):
        return np.clip(np.asarray(base, float) + rng.uniform(-spread, spread, 3), 0.05, 0.95)

    # room shell (normals point into the room)
    size = hi - lo
    ex, ey, ez = np.eye(3)
    shell = [
        ("floor", "floor", lo, size[0] * ex, size[1] * ey, (8, 7), pal([0.62, 0.45, 0.30]), pal([0.40, 0.28, 0.18])),
        ("ceiling", "ceiling", lo + size[2] * ez, size[0] * ex, size[1] * ey, (4, 4), pal([0.90, 0.89, 0.85], 0.03), pal([0.80, 0.80, 0.78], 0.03)),
        ("wall_south", "wall", lo, size[0] * ex, size[2] * ez, (8, 3), pal([0.75, 0.70, 0.55]), pal([0.55, 0.62, 0.70])),
        ("wall_north", "wall", lo + size[1] * ey, size[0] * ex, size[2] * ez, (8, 3), pal([0.55, 0.68, 0.60]), pal([0.85, 0.82, 0.70])),
        ("wall_west", "wall", lo, size[1] * ey, size[2] * ez, (7, 3), pal([0.70, 0.55, 0.55]), pal([0.88, 0.80, 0.72])),
        ("wall_east", "wall", lo + size[0] * ex, size[1] * ey, size[2] * ez, (7, 3), pal([0.52, 0.56, 0.75]), pal([0.86, 0.84, 0.80])),
    ]
    for name, kind, o, du, dv, (nu, nv), c1, c2 in shell:
        v, f = _grid_quad(o, du, dv, nu, nv)
        parts.append((v, _orient(v, f, room_c, outward=False), _Obj(name, kind, c1, c2, room_c)))

    # table: top + 4 legs
    tc = np.array([0.3 + jit(0.2), 0.2 + jit(0.2), 0.0])
    tyaw = jit(0.3)
    top_h, top_size = 0.74, np.array([1.3, 0.8, 0.06])
    tv, tf = [], []
    off = 0
    c, s = math.cos(tyaw), math.sin(tyaw)
    Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    pieces = [(np.array([0, 0, top_h - 0.03]), top_size)]
    for sx in (-1, 1):
        for sy in (-1, 1):
            pieces.append((np.array([sx * 0.56, sy * 0.33, (top_h - 0.06) / 2]), np.array([0.06, 0.06, top_h - 0.06])))
    for pc, ps in pieces:
        v, f = _box(tc + Rz @ pc, ps, tyaw, n=2 if ps[0] > 1 else 1)
        f = _orient(v, f, tc + Rz @ pc)
        tv.append(v)
        tf.append(f + off)
        off += len(v)
    parts.append((np.concatenate(tv), np.concatenate(tf), _Obj("table", "wood", pal([0.55, 0.36, 0.20]), pal([0.35, 0.22, 0.12]), tc)))

    # boxes
    boxes = [
        ("box_crate", np.array([-1.7 + jit(0.15), -1.0 + jit(0.15)]), np.array([0.65, 0.55, 0.5]), pal([0.80, 0.35, 0.25]), pal([0.95, 0.85, 0.60])),
        ("box_tall", np.array([1.9 + jit(0.1), -1.3 + jit(0.1)]), np.array([0.45, 0.45, 1.1]), pal([0.25, 0.45, 0.75]), pal([0.90, 0.90, 0.95])),
        ("box_small", None, np.array([0.26, 0.22, 0.2]), pal([0.30, 0.65, 0.35]), pal([0.95, 0.95, 0.55])),
    ]
    for name, xy, sz, c1, c2 in boxes:
        if xy is None:  # on the table
            cen = tc + Rz @ np.array([-0.35, 0.1, top_h + sz[2] / 2])
        else:
            cen = np.array([xy[0], xy[1], sz[2] / 2])
        v, f = _box(cen, sz, jit(0.6), n=2)
        parts.append((v, _orient(v, f, cen), _Obj(name, "box", c1, c2, cen)))

    # sphere on the floor and vase on the table
    sc = np.array([-1.3 + jit(0.15), 1.3 + jit(0.15), 0.38])
    v, f = _icosphere(sc, 0.38, subdiv=2)
    parts.append((v, _orient(v, f, sc), _Obj("sphere", "dots", pal([0.85, 0.80, 0.30]), pal([0.55, 0.20, 0.45]), sc)))
    vc = tc + Rz @ np.array([0.3, -0.1, top_h])
    v, f = _cylinder(vc, 0.11, 0.34)
    parts.append((v, _orient(v, f, vc + np.array([0, 0, 0.17])), _Obj("vase", "bands", pal([0.20, 0.55, 0.60]), pal([0.92, 0.92, 0.88]), vc)))

    verts, faces, fobj, objs = [], [], [], []
    off = 0
    for k, (v, f, o) in enumerate(parts):
        verts.append(v)
        faces.append(f + off)
        fobj.append(np.full(len(f), k, np.int32))
        objs.append(o)
        off += len(v)
    return np.concatenate(verts), np.concatenate(faces).astype(np.int64), np.concatenate(fobj), objs


# --------------------------------------------------------------------------- textures & shading
def _hash2(i, j):
    x = np.sin(i * 12.9898 + j * 78.233) * 43758.5453
    return x - np.floor(x)


def albedo(points, obj_ids, objs):
    """Procedural albedo at 3D surface points ``[P,3]`` of objects ``obj_ids [P]`` -> ``[P,3]``."""
    out = np.zeros((len(points), 3))
    for k, o in enumerate(objs):
        sel = obj_ids == k
        if not np.any(sel):
            continue
        p = points[sel] - o.center
        c1, c2 = o.color, o.color2
        if o.kind == "floor":
            s = 0.5
            ix, iy = np.floor(points[sel, 0] / s), np.floor(points[sel, 1] / (2 * s))
            fx = points[sel, 0] / s - ix
            fy = points[sel, 1] / (2 * s) - iy
            h = _hash2(ix, iy)[:, None]
            grain = 0.5 + 0.5 * np.sin(points[sel, 1] * 9.0 + 2 * np.sin(points[sel, 0] * 3.1 + h[:, 0] * 6))
            col = c1 * (0.75 + 0.35 * h) * (0.85 + 0.15 * grain[:, None])
            grout = (np.minimum(fx, 1 - fx) < 0.04) | (np.minimum(fy, 1 - fy) < 0.02)
            col[grout] = c2 * 0.6
        elif o.kind == "wall":
            u = points[sel, 0] + points[sel, 1]
            z = points[sel, 2]
            stripe = (0.5 + 0.5 * np.sin(2 * np.pi * u / 0.6)) ** 2
            t = np.clip(stripe, 0, 1)[:, None]
            col = c1 * (1 - 0.45 * t) + c2 * 0.45 * t
            rail = np.abs(z - 0.9) < 0.04
            col[rail] = c2 * 0.5
            diamond = (np.abs(((u / 0.8) % 1) - 0.5) + np.abs(((z / 0.8) % 1) - 0.5)) < 0.12
            col[diamond & (z > 1.0)] = c1 * 0.45
        elif o.kind == "ceiling":
            g = (np.abs(((points[sel, 0] / 1.0) % 1) - 0.5) < 0.03) | (np.abs(((points[sel, 1] / 1.0) % 1) - 0.5) < 0.03)
            col = np.where(g[:, None], c2 * 0.7, c1)
        elif o.kind == "wood":
            r = p[:, 0] * 25 + 2.5 * np.sin(p[:, 1] * 7 + p[:, 2] * 5)
            t = (0.5 + 0.5 * np.sin(r))[:, None]
            col = c1 * (1 - t) + c2 * t
        elif o.kind == "box":
            s = 0.09
            chk = (np.floor(p[:, 0] / s + 1e-6) + np.floor(p[:, 1] / s + 1e-6) + np.floor(p[:, 2] / s + 1e-6)) % 2
            col = np.where(chk[:, None] > 0, c1, c2)
        elif o.kind == "dots":
            d = p / np.maximum(np.linalg.norm(p, axis=1, keepdims=True), 1e-9)
            az = np.arctan2(d[:, 1], d[:, 0])
            el = np.arcsin(np.clip(d[:, 2], -1, 1))
            dot = np.sin(az * 6) * np.sin(el * 6 + 0.5) > 0.55
            band = np.abs(el) < 0.08
            col = np.where((dot | band)[:, None], c2, c1)
        elif o.kind == "bands":
            t = (np.sin(p[:, 2] * 60 + 2 * np.arctan2(p[:, 1], p[:, 0])) > 0.2)[:, None]
            col = np.where(t, c1, c2)
        else:  # pragma: no cover
            col = np.broadcast_to(c1, (int(sel.sum()), 3))
        out[sel] = col
    return np.clip(out, 0, 1)


def shade(points, normals):
    """View-independent lighting factor ``[P]``: ambient + sun (Lambert) + a soft lamp."""
    sun = np.clip(normals @ LIGHT_DIR, 0, None)
    to_lamp = LAMP - points
    d2 = np.einsum("ij,ij->i", to_lamp, to_lamp)
    lamp = np.clip(np.einsum("ij,ij->i", normals, to_lamp) / np.sqrt(d2 + 1e-12), 0, None) * 2.2 / (1 + d2)
    return 0.42 + 0.33 * sun + 0.35 * lamp


def surface_color(points, face_ids, mesh):
    """Shaded colour ``[P,3]`` in [0,1] at surface points lying on faces ``face_ids``."""
    verts, faces, fobj, objs = mesh
    v = verts[faces[face_ids]]
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    return np.clip(albedo(points, fobj[face_ids], objs) * shade(points, n)[:, None], 0, 1)


def render_view(mesh, cam: Camera, ss: int = 3):
    """Render one view: ``(image [H,W,3] float32, object ids [H,W] int16, depth [H,W] float32)``.

    The colour is the average of ``ss x ss`` samples per pixel (anti-aliased); ids and depth
    come from the pixel-centre sample (the middle one when ``ss`` is odd, else a second pass).
    """
    verts, faces, fobj, objs = mesh
    face, depth, point = rasterize(verts, faces, cam, ss=ss)
    H, W = cam.height, cam.width
    col = np.zeros((H * ss, W * ss, 3))
    hit = face >= 0
    col[hit] = surface_color(point[hit], face[hit], mesh)
    img = col.reshape(H, ss, W, ss, 3).mean((1, 3)).astype(np.float32)
    if ss % 2 == 1:
        c = ss // 2
        face_c, depth_c = face[c::ss, c::ss], depth[c::ss, c::ss]
    else:
        face_c, depth_c, _ = rasterize(verts, faces, cam, ss=1)
    ids = np.where(face_c >= 0, fobj[np.maximum(face_c, 0)], -1).astype(np.int16)
    return img, ids, np.where(np.isfinite(depth_c), depth_c, 0.0).astype(np.float32)


# --------------------------------------------------------------------------- cameras & points
def make_cameras(n: int, width: int, height: int, seed: int = 0, hfov_deg: float = 68.0):
    """``n`` cameras on a loop around the furniture, looking at it (deterministic for ``seed``)."""
    rng = np.random.default_rng(seed + 1000)
    f = 0.5 * width / math.tan(math.radians(hfov_deg) / 2)
    cams = []
    for k in range(n):
        a = 2 * np.pi * k / n + rng.uniform(-0.5, 0.5) * (np.pi / n) + 0.3
        C = np.array([2.45 * math.cos(a), 1.95 * math.sin(a), 1.35 + rng.uniform(-0.2, 0.25)])
        target = np.array([0.0, 0.0, 0.55]) + rng.uniform(-0.45, 0.45, 3) * np.array([1, 1, 0.4])
        fwd = target - C
        fwd /= np.linalg.norm(fwd)
        right = np.cross(fwd, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        down = np.cross(fwd, right)
        R = np.stack([right, down, fwd])
        m = np.eye(4)
        m[:3, :3] = R
        m[:3, 3] = -R @ C
        cams.append(Camera(width, height, f, f, width / 2, height / 2, m))
    return cams


def sample_surface(mesh, n: int, rng):
    """``n`` points uniformly on the mesh by area: ``(points [n,3], face ids [n])``."""
    verts, faces = mesh[0], mesh[1]
    v = verts[faces]
    a = 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)
    fi = rng.choice(len(faces), n, p=a / a.sum())
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    b = np.stack([1 - s, s * (1 - r2), s * r2], 1)
    return np.einsum("nk,nkj->nj", b, v[fi]), fi


def visibility(points, cameras, depths, rel_tol: float = 0.01, abs_tol: float = 0.01):
    """``[P, N]`` bool: point visible in view (inside the image and not occluded per ``depths``)."""
    vis = np.zeros((len(points), len(cameras)), bool)
    for k, (cam, dep) in enumerate(zip(cameras, depths)):
        xc = points @ cam.R.T + cam.t
        z = xc[:, 2]
        ok = z > NEAR
        u = np.where(ok, cam.fx * xc[:, 0] / np.where(ok, z, 1) + cam.cx, -1)
        v = np.where(ok, cam.fy * xc[:, 1] / np.where(ok, z, 1) + cam.cy, -1)
        ok &= (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
        j = np.clip(u.astype(int), 0, cam.width - 1)
        i = np.clip(v.astype(int), 0, cam.height - 1)
        d = dep[i, j]
        vis[:, k] = ok & (np.abs(d - z) <= rel_tol * z + abs_tol)
    return vis


def load_procedural(size: str = "tiny", seed: int = 0, split="auto", point_noise: float = 0.005,
                    num_points=None, ss=None) -> Scene:
    """The built-in procedural indoor scene.

    Args:
        size: ``"tiny"`` (64x48, 8 views; unit tests), ``"small"`` (160x120, 24 views) or
            ``"demo"`` (320x240, 40 views).
        seed: layout, colours, cameras and points all follow from it.
        split: as for :func:`~tsplus_wgpu.data.load_scene` (default: every 8th view held out).
        point_noise: standard deviation (metres) of Gaussian noise added to the SfM-like points.
        num_points: surface samples drawn before the visibility filter (default by size).
        ss: supersampling per axis (default 3 for tiny, 2 otherwise).

    Returns:
        a :class:`~tsplus_wgpu.data.scene.Scene` with ``gt_mesh``, per-view object ``masks`` and
        ``depths``; points are surface samples seen by at least two views, coloured exactly as rendered,
        with the views that see them (before ``point_noise``) as ``point_tracks``.
    """
    from .errors import SceneError  # noqa: PLC0415
    if size not in SIZES:
        raise SceneError(f"procedural size {size!r}: expected one of {', '.join(SIZES)}")
    width, height, nviews, npts, ss_default = SIZES[size]
    ss = ss_default if ss is None else int(ss)
    mesh = build_world(seed)
    cams = make_cameras(nviews, width, height, seed)
    images, masks, depths = [], [], []
    for cam in cams:
        img, ids, dep = render_view(mesh, cam, ss=ss)
        images.append(img)
        masks.append(ids)
        depths.append(dep)
    rng = np.random.default_rng(seed + 2000)
    pts, fi = sample_surface(mesh, int(num_points or npts), rng)
    vis = visibility(pts, cams, depths)
    keep = vis.sum(1) >= 2
    pts, fi = pts[keep], fi[keep]
    tracks = from_mask(vis[keep])
    cols = surface_color(pts, fi, mesh)
    if point_noise:
        pts = pts + rng.normal(0.0, point_noise, pts.shape)
    train, test, rule = make_split(len(cams), split)
    verts, faces, fobj, objs = mesh
    return Scene(format="procedural", cameras=cams, images=images,
                 image_names=[f"view_{k:03d}.png" for k in range(nviews)], points=pts, point_colors=cols,
                 point_tracks=tracks, points_source="procedural", train_indices=train, test_indices=test, warnings=[],
                 root=None, background=(0.0, 0.0, 0.0), camera_models={"PINHOLE": nviews},
                 split_rule=rule, gt_mesh=GTMesh(verts, faces, fobj, [o.name for o in objs]),
                 masks=masks, depths=depths)


# --------------------------------------------------------------------------- normal maps
def render_normal_map(mesh, cam: Camera) -> np.ndarray:
    """The ground-truth normal map of one view: ``[H, W, 3]`` float32, the visible face's unit
    normal in camera space (OpenCV: x right, y down, z forward) facing the camera, sampled at
    the pixel centres; zero where no surface is seen. This is the convention of
    ``tsplus train --normals`` (:mod:`tsplus_wgpu.data.normals`)."""
    verts, faces = mesh[0], mesh[1]
    face, _, point = rasterize(verts, faces, cam, ss=1)
    n_world = np.cross(verts[faces[:, 1]] - verts[faces[:, 0]], verts[faces[:, 2]] - verts[faces[:, 0]])
    n_world /= np.maximum(np.linalg.norm(n_world, axis=1, keepdims=True), 1e-300)
    hit = face >= 0
    out = np.zeros((cam.height, cam.width, 3))
    n = n_world[face[hit]] @ cam.R.T
    x = point[hit] @ cam.R.T + cam.t
    flip = np.einsum("pi,pi->p", n, x) > 0
    n[flip] *= -1.0
    out[hit] = n
    return out.astype(np.float32)


def normal_maps(scene) -> list:
    """Ground-truth normal maps (:func:`render_normal_map`) of every view of a scene with a
    ground-truth mesh (the procedural scene), in view order."""
    if scene.gt_mesh is None:
        raise ValueError("scene: it has no ground-truth mesh (only the procedural scene has one)")
    g = scene.gt_mesh
    return [render_normal_map((g.vertices, g.faces), cam) for cam in scene.cameras]


def demo_model(seed: int = 0):
    """The procedural scene's ground-truth mesh as an opaque, vertex-coloured
    :class:`~tsplus_wgpu.TriangleModel` (SH degree 0, opacity 1)."""
    from ..types import SH_C0, TriangleModel
    verts, faces, fobj, objs = mesh = build_world(seed)
    face_of_vertex = np.zeros(len(verts), np.int64)
    face_of_vertex[faces.ravel()] = np.repeat(np.arange(len(faces)), 3)
    colors = surface_color(verts, face_of_vertex, mesh)
    sh = ((colors - 0.5) / SH_C0)[:, None, :]
    return TriangleModel(verts, faces, sh, np.ones(len(verts)))
