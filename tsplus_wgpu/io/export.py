"""Engine-ready output: PLY / GLB / OBJ through trimesh, the PLY reader back into a
:class:`~tsplus_wgpu.TriangleModel`, colour baking and the connectivity report. Reading what ``tsplus train`` wrote (run folders, checkpoints) is
:func:`tsplus_wgpu.apps.runs.load_run`.

PLY layout (binary little endian, written by trimesh): ``x y z`` float32, ``red green blue
alpha`` uint8 (the baked colour), ``f_dc_0..2`` and ``f_rest_0..3(K-1)-1`` float32 (SH,
``f_rest`` channel-major as 3DGS writes it: all R coefficients, then G, then B) and
``opacity`` float32 (activated, in [0, 1]); faces ``vertex_indices`` (uchar count, int32).
A float32-valued model (as the trainer's) round-trips bit for bit.

GLB: glTF 2.0 with ``POSITION`` and ``COLOR_0`` (linear floats), one unlit, double-sided
material (:mod:`.gltf` says why). ``rotation`` (a 3x3 rotation, e.g.
:func:`~tsplus_wgpu.data.upright.engine_rotation`: the cameras' up to +Y) turns the world into an
engine's frame (a 4x4 similarity, :func:`~tsplus_wgpu.apps.placement.engine_frame`, also moves the
origin onto the ground and scales the lengths); ``y_up`` is the fixed one for worlds whose -y is up (OpenCV's y down, z forward),
a rotation of 180 degrees about x, ``(x, -y, -z)``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..types import SH_C0, TriangleModel
from .atomic import write_bytes, write_error

FORMATS = ("ply", "glb", "obj")
BAKES = ("mesh", "dc", "fit", "views")


class ExportError(ValueError):
    """A user's mistake (missing run, empty mesh, unknown format, unwritable path): one line."""


# ----------------------------------------------------------------------------- colours

def dc_colors(model: TriangleModel) -> np.ndarray:
    """[N, 3] colour in [0, 1] from the SH DC term (the view-independent part)."""
    return np.clip(model.sh[:, 0] * SH_C0 + 0.5, 0.0, 1.0)


def to_uint8(colors) -> np.ndarray:
    return np.round(np.clip(np.asarray(colors, np.float64), 0.0, 1.0) * 255).astype(np.uint8)


def bake_views(model: TriangleModel, scene, views=None, mesh_renderer=None, near=None, depth_tol=0.01):
    """Per-vertex colour averaged over the training views where the vertex is visible:
    each view is drawn by the :class:`~tsplus_wgpu.MeshRenderer` (its depth decides
    visibility: camera z within ``depth_tol`` relative of the surface at the vertex's pixel)
    and the photo is sampled at the vertex's projection. Vertices no view sees keep the
    DC colour. ``near``: near plane in world units (default: the training default relative to
    the scene's camera radius, ``scene.frame().near_world()``). Returns ``(colors [N, 3],
    views_seen [N])``."""
    from ..render.mesh_renderer import MeshRenderer
    mr = mesh_renderer or MeshRenderer()
    near = scene.frame().near_world() if near is None else near
    views = list(scene.train_indices or range(len(scene.cameras))) if views is None else list(views)
    base = dc_colors(model)
    acc = np.zeros_like(base)
    cnt = np.zeros(model.num_vertices)
    for v in views:
        cam, img = scene.cameras[v], np.asarray(scene.images[v], np.float64)
        depth = mr.render((model.positions, model.triangles, base), cam, near=near).depth
        pc = model.positions @ cam.R.T + cam.t
        z = pc[:, 2]
        ok = z > near
        zs = np.where(ok, z, 1.0)
        u = cam.fx * pc[:, 0] / zs + cam.cx
        vv = cam.fy * pc[:, 1] / zs + cam.cy
        j, i = np.floor(u).astype(np.int64), np.floor(vv).astype(np.int64)
        ok &= (j >= 0) & (j < cam.width) & (i >= 0) & (i < cam.height)
        jj, ii = np.where(ok, j, 0), np.where(ok, i, 0)
        d = depth[ii, jj]
        ok &= (d > 0) & (z <= d * (1 + depth_tol))
        acc[ok] += img[ii[ok], jj[ok]]
        cnt[ok] += 1
    out = np.where(cnt[:, None] > 0, acc / np.maximum(cnt, 1)[:, None], base)
    return out, cnt


# ----------------------------------------------------------------------------- connectivity

def connectivity(triangles, num_vertices=None) -> dict:
    """The paper's connectivity figures of a triangle set: mean triangles per (used) vertex,
    share of triangles that share a vertex with another, connected components (triangles
    joined through shared vertices), non-manifold edges (in more than two triangles) and
    boundary edges (in one)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    tri = np.asarray(triangles, np.int64).reshape(-1, 3)
    m = len(tri)
    n = int(num_vertices if num_vertices is not None else (tri.max() + 1 if m else 0))
    if m == 0:
        return dict(triangles=0, vertices=n, used_vertices=0, triangles_per_vertex=0.0, shared_vertex_share=0.0,
                    components=0, non_manifold_edges=0, boundary_edges=0, edges=0)
    inc = np.bincount(tri.ravel(), minlength=n)
    used = inc > 0
    shares = (inc[tri] >= 2).any(axis=1)
    # components over the used vertices: each triangle links its three vertices
    rows = np.concatenate([tri[:, 0], tri[:, 1]])
    cols = np.concatenate([tri[:, 1], tri[:, 2]])
    g = coo_matrix((np.ones(len(rows), np.int8), (rows, cols)), shape=(n, n))
    _, labels = connected_components(g, directed=False)
    components = len(np.unique(labels[used]))
    e = np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    return dict(triangles=m, vertices=n, used_vertices=int(used.sum()),
                triangles_per_vertex=float(inc[used].mean()), shared_vertex_share=float(shares.mean()),
                components=int(components), non_manifold_edges=int((counts > 2).sum()),
                boundary_edges=int((counts == 1).sum()), edges=int(len(counts)))


def connectivity_line(c: dict) -> str:
    return (f"connectivity: {c['used_vertices']} vertices, {c['triangles']} triangles, "
            f"{c['triangles_per_vertex']:.2f} triangles per vertex, {100 * c['shared_vertex_share']:.1f}% of "
            f"triangles share a vertex, {c['components']} connected components, {c['non_manifold_edges']} "
            f"non-manifold edges, {c['boundary_edges']} boundary edges")


# ----------------------------------------------------------------------------- writing

def _atomic_bytes(path, data: bytes):
    path = Path(path)
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise ExportError(f"--out {path}: folder {parent} does not exist")
    if path.is_dir():
        raise ExportError(f"--out {path}: is a folder")
    try:
        write_bytes(path, data)
    except OSError as exc:                      # a WriteError: names the path, the cause and the fix
        raise ExportError(f"--out {write_error(path, exc)}") from None


def _trimesh(positions, triangles, colors):
    import trimesh
    rgba = np.concatenate([to_uint8(colors), np.full((len(positions), 1), 255, np.uint8)], axis=1)
    return trimesh.Trimesh(vertices=np.asarray(positions, np.float64), faces=np.asarray(triangles, np.int64),
                           vertex_colors=rgba, process=False, validate=False)


def encode_ply(model: TriangleModel, colors=None) -> bytes:
    """The PLY bytes of ``model`` (see the module header) with ``colors`` (default: SH DC)."""
    colors = dc_colors(model) if colors is None else colors
    mesh = _trimesh(model.positions.astype(np.float32), model.triangles, colors)
    sh = model.sh.astype(np.float32)
    for c in range(3):
        mesh.vertex_attributes[f"f_dc_{c}"] = np.ascontiguousarray(sh[:, 0, c])
    rest = sh[:, 1:, :].transpose(0, 2, 1).reshape(model.num_vertices, -1)   # [N, 3*(K-1)], channel-major
    for i in range(rest.shape[1]):
        mesh.vertex_attributes[f"f_rest_{i}"] = np.ascontiguousarray(rest[:, i])
    mesh.vertex_attributes["opacity"] = model.opacity.astype(np.float32)
    return mesh.export(file_type="ply", encoding="binary")


#: the fixed rotation of ``y_up``: 180 degrees about x
Y_UP = np.diag([1.0, -1.0, -1.0])


def frame_matrix(frame) -> np.ndarray | None:
    """``frame`` (None, a 3x3 rotation or a 4x4 similarity ``s R | t``) as a 4x4 float64
    matrix, checked: ``s > 0``, ``R`` a rotation; None stays None."""
    if frame is None:
        return None
    f = np.asarray(frame, np.float64)
    if f.shape == (3, 3):
        f = np.vstack([np.hstack([f, np.zeros((3, 1))]), [0.0, 0.0, 0.0, 1.0]])
    if f.shape != (4, 4) or not np.all(np.isfinite(f)) or not np.allclose(f[3], [0, 0, 0, 1]):
        raise ExportError("frame: not a 3x3 rotation or a 4x4 similarity; nothing written")
    det = np.linalg.det(f[:3, :3])
    s = np.cbrt(det) if det > 0 else 0.0
    if not s > 0 or not np.allclose(f[:3, :3] @ f[:3, :3].T / (s * s), np.eye(3), atol=1e-9):
        raise ExportError("frame: not a rotation with a positive scale; nothing written")
    return f


def _placed(positions, frame=None):
    """``positions`` (float64) taken through ``frame`` (:func:`frame_matrix`; None: as they are)."""
    pos = np.asarray(positions, np.float64)
    f = frame_matrix(frame)
    return pos if f is None else pos @ f[:3, :3].T + f[:3, 3]


#: where a GLB (``asset.extras``), an OBJ or a PLY (a header comment) records the frame its positions
#: were written in, so that reading it back gives the world again (``tsplus eval`` of an upright GLB):
#: a 3x3 rotation, or a 4x4 similarity when the export also moved the origin or scaled (``--origin``,
#: ``--scale``)
FRAME_KEY = "tsplus_world_to_file"


def _rotation(y_up, rotation):
    """The frame an export applies: ``rotation`` (3x3 or 4x4), else the fixed ``Y_UP`` when ``y_up``, else None."""
    return Y_UP if y_up and rotation is None else rotation


def _recorded(frame):
    """What is recorded of a frame: its rotation alone where it is one (as before similarities), else 4x4."""
    f = frame_matrix(frame)
    return f[:3, :3] if np.allclose(f[:3, 3], 0) and np.allclose(f[:3, :3] @ f[:3, :3].T, np.eye(3), atol=1e-12) \
        else f


def _record(rot) -> str:
    """``FRAME_KEY`` and the frame's 9 (rotation) or 12 (the top three rows of the similarity) numbers,
    exactly (the OBJ / PLY header comment)."""
    r = _recorded(rot)
    return f"{FRAME_KEY} " + " ".join(f"{v:.17g}" for v in (r if r.shape == (3, 3) else r[:3]).ravel())


def encode_glb(positions, triangles, colors, y_up=False, rotation=None) -> bytes:
    """The GLB an engine reads (:mod:`.gltf`: unlit, double-sided, linear ``COLOR_0``), in the
    frame ``rotation`` (or ``y_up``), which is recorded in ``asset.extras``."""
    from .gltf import encode_glb as glb  # noqa: PLC0415
    rot = _rotation(y_up, rotation)
    extras = None if rot is None else {FRAME_KEY: _recorded(rot).tolist()}
    return glb(_placed(positions, rot), triangles, colors, extras)


def encode_obj(positions, triangles, colors, y_up=False, rotation=None) -> bytes:
    from trimesh.exchange.obj import export_obj
    rot = _rotation(y_up, rotation)
    mesh = _trimesh(_placed(positions, rot), triangles, colors)
    header = "tsplus-wgpu mesh, vertex colours as 'v x y z r g b'"
    if rot is not None:
        header += f"\n# {_record(rot)}"
    text = export_obj(mesh, include_normals=False, include_color=True, include_texture=False, digits=9,
                      header=header)
    return text.encode()


def file_frame(path) -> np.ndarray | None:
    """The 4x4 frame ``F`` a GLB, OBJ or PLY of ours was written in (positions ``F @ [p, 1]`` of the
    world points ``p``), or None: another program's file, or written in the world's own frame."""
    import json
    import re

    from .gltf import json_chunk_length
    path = Path(path)
    try:
        with open(path, "rb") as f:
            head = f.read(1 << 16)
        n = json_chunk_length(head)
        if n is not None:
            with open(path, "rb") as f:
                f.seek(20)
                tree = json.loads(f.read(n))
            rec = np.asarray(tree["asset"]["extras"][FRAME_KEY], np.float64)
        else:
            m = re.search(rb"^(?:# |comment )" + FRAME_KEY.encode() + rb"((?: +\S+){9}(?:(?: +\S+){3})?) *$", head,
                          re.MULTILINE)
            if m is None:
                return None
            vals = np.array([float(v) for v in m.group(1).split()])
            rec = vals.reshape(3, 3) if len(vals) == 9 else np.vstack([vals.reshape(3, 4), [0.0, 0.0, 0.0, 1.0]])
        return frame_matrix(rec)
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None


def export(model: TriangleModel, path, fmt=None, colors=None, y_up=False, rotation=None):
    """Write ``model`` to ``path`` atomically (temp file + os.replace; nothing is left
    behind on error). ``fmt`` defaults to the file's extension; ``colors`` to SH DC;
    ``rotation`` (a 3x3 rotation, or a 4x4 similarity: :func:`frame_matrix`) takes the positions to
    the file's frame, else ``y_up`` the fixed ``(x, -y, -z)``; the frame is recorded in the file."""
    path = Path(path)
    fmt = (fmt or path.suffix.lstrip(".")).lower()
    if fmt not in FORMATS:
        raise ExportError(f"--format {fmt or '(none)'}: unknown format; choose one of {', '.join(FORMATS)}")
    if model.num_triangles == 0:
        raise ExportError("the mesh has no triangles; nothing to export")
    colors = dc_colors(model) if colors is None else np.asarray(colors, np.float64)
    rot = _rotation(y_up, rotation)
    frame_matrix(rot)                            # a bad frame is refused before anything is written
    if fmt == "ply":
        if rot is not None:
            model = TriangleModel(_placed(model.positions, rot), model.triangles, model.sh, model.opacity)
        data = encode_ply(model, colors)
        if rot is not None:                      # recorded as a header comment after the format line
            at = data.index(b"\n", data.index(b"format ")) + 1
            data = data[:at] + f"comment {_record(rot)}\n".encode() + data[at:]
    elif fmt == "glb":
        data = encode_glb(model.positions, model.triangles, colors, rotation=rot)
    else:
        data = encode_obj(model.positions, model.triangles, colors, rotation=rot)
    _atomic_bytes(path, data)
    return path


# ----------------------------------------------------------------------------- reading

_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
              "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
              "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


def _parse_binary_ply(data: bytes):
    """(vertex structured array, faces [M, 3]) of a binary little-endian PLY whose faces
    are all triangles; None when the file is anything else (trimesh reads those)."""
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply") or end < 0:
        return None
    header = data[:end].decode("ascii", "replace").splitlines()
    if "format binary_little_endian 1.0" not in [h.strip() for h in header]:
        return None
    elements, cur = [], None
    for line in header:
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "element":
            cur = [parts[1], int(parts[2]), []]
            elements.append(cur)
        elif parts[0] == "property" and cur is not None:
            if parts[1] == "list":
                cur[2].append((parts[4], "list", parts[2], parts[3]))
            else:
                cur[2].append((parts[2], _PLY_TYPES[parts[1]]))
    off = end + len(b"end_header\n")
    vertex, faces = None, None
    for name, count, props in elements:
        if name == "vertex":
            if any(p[1] == "list" for p in props):
                return None
            dt = np.dtype([(p[0], "<" + p[1]) for p in props])
            vertex = np.frombuffer(data, dt, count, off)
            off += dt.itemsize * count
        elif name == "face":
            if len(props) != 1 or props[0][1] != "list":
                return None
            ct, it = _PLY_TYPES[props[0][2]], _PLY_TYPES[props[0][3]]
            dt = np.dtype([("n", "<" + ct), ("i", "<" + it, (3,))])
            if count and off + dt.itemsize * count > len(data):
                return None
            f = np.frombuffer(data, dt, count, off)
            if count and not np.all(f["n"] == 3):
                return None
            faces = f["i"].astype(np.int64)
            off += dt.itemsize * count
        else:
            return None
    if vertex is None:
        return None
    return vertex, (faces if faces is not None else np.zeros((0, 3), np.int64))


def read_ply(path) -> TriangleModel:
    """A :class:`TriangleModel` from a PLY: this module's layout gives SH and opacity back
    exactly; any other coloured mesh PLY gives SH DC from its colours and opacity 1."""
    path = Path(path)
    try:
        return _model_from_ply(path, path.read_bytes())
    except ExportError:
        raise
    except ValueError as exc:                   # truncated data, NaN vertices, bad indices, ...
        raise ExportError(f"{path}: {exc}; not a usable mesh") from None


def read_ply_colors(path):
    """``[N, 3]`` float64 in [0, 1]: the vertex colour (``red green blue``, what an engine
    draws) of a binary PLY, or None where it has none or is not binary (then the model's SH
    DC is its colour)."""
    try:
        parsed = _parse_binary_ply(Path(path).read_bytes())
    except (OSError, ValueError):
        return None
    if parsed is None or not {"red", "green", "blue"} <= set(parsed[0].dtype.names):
        return None
    v = parsed[0]
    return np.stack([v["red"], v["green"], v["blue"]], 1).astype(np.float64) / 255.0


def _model_from_ply(path, data: bytes) -> TriangleModel:
    parsed = _parse_binary_ply(data)
    if parsed is not None:
        v, faces = parsed
        names = v.dtype.names
        pos = np.stack([v["x"], v["y"], v["z"]], 1).astype(np.float64)
        if "f_dc_0" in names:
            n_rest = sum(1 for k in names if k.startswith("f_rest_"))
            k = 1 + n_rest // 3
            sh = np.zeros((len(v), k, 3))
            sh[:, 0] = np.stack([v[f"f_dc_{c}"] for c in range(3)], 1)
            if n_rest:
                rest = np.stack([v[f"f_rest_{i}"] for i in range(n_rest)], 1).reshape(len(v), 3, k - 1)
                sh[:, 1:] = rest.transpose(0, 2, 1)
            op = np.asarray(v["opacity"], np.float64) if "opacity" in names else np.ones(len(v))
            return TriangleModel(pos, faces, sh, op)
        if "red" in names:
            col = np.stack([v["red"], v["green"], v["blue"]], 1).astype(np.float64) / 255.0
        else:
            col = np.full((len(v), 3), 0.5)
        return TriangleModel(pos, faces, ((col - 0.5) / SH_C0)[:, None, :], np.ones(len(v)))
    return read_mesh(path)


def read_mesh(path) -> TriangleModel:
    """Any mesh trimesh reads (PLY, GLB, OBJ, ...) as an opaque model with SH DC from its
    vertex colours (grey when it has none)."""
    import trimesh
    try:
        m = trimesh.load(str(path), force="mesh", process=False)
    except Exception as exc:
        raise ExportError(f"{path}: not a readable mesh ({exc})") from None
    pos = np.asarray(m.vertices, np.float64)
    faces = np.asarray(m.faces, np.int64).reshape(-1, 3)
    col = np.full((len(pos), 3), 0.5)
    try:
        vc = m.visual.vertex_colors
        if vc is not None and len(vc) == len(pos):
            col = np.asarray(vc, np.float64)[:, :3] / 255.0
    except Exception:
        pass
    if Path(path).suffix.lower() == ".glb":         # COLOR_0 is linear light: read it as such, into sRGB
        from .gltf import glb_colors  # noqa: PLC0415
        try:
            lin = glb_colors(Path(path).read_bytes())
        except OSError:
            lin = None
        if lin is not None and len(lin) == len(pos):
            col = lin
    try:
        return TriangleModel(pos, faces, ((col - 0.5) / SH_C0)[:, None, :], np.ones(len(pos)))
    except ValueError as exc:                   # NaN vertices, indices out of range, ...
        raise ExportError(f"{path}: {exc}; not a usable mesh") from None
