"""The GLB the export writes, and the vertex colours of a GLB read back.

What an engine needs from a mesh of baked, opaque, vertex-coloured triangles, by the glTF 2.0
specification:

* **One material**, unlit (``KHR_materials_unlit``): the colours are the photos' light already,
  so an engine's own lighting must not shade them again. Engines without the extension fall back
  to its metallic-roughness part: not metallic (``metallicFactor`` 0), fully rough. Without any
  material a primitive gets glTF's default one, which is fully *metallic*: a metal has no diffuse
  colour, so under an engine's lights the mesh drew dark.
* **Double-sided** (``doubleSided``): the trained triangles come from a Delaunay
  tetrahedralisation and topology edits, so their winding says nothing about which side the
  photos saw (about half of the shared cup's triangles face their nearest camera, a quarter of
  lund's).
  A single-sided material, glTF's default, lets an engine cull every triangle seen from behind.
* **``COLOR_0`` in linear light**, as the specification defines it, as 32-bit floats: the photos'
  colours are sRGB-encoded, and an engine encodes its output to sRGB itself, so colours written
  as they are came out too bright. Floats keep the dark colours exact (8-bit linear values have
  two levels below sRGB 20).

:func:`glb_colors` reads ``COLOR_0`` of any GLB back into sRGB (the colour space everything else
here works in): floats, normalised bytes or shorts, as the specification allows.
"""

from __future__ import annotations

import json
import struct

import numpy as np

#: glTF's component types: id -> (NumPy type, the divisor of a normalised integer)
_COMPONENTS = {5126: ("<f4", None), 5121: ("<u1", 255.0), 5123: ("<u2", 65535.0)}
_GLB_MAGIC, _JSON, _BIN = 0x46546C67, 0x4E4F534A, 0x004E4942


def srgb_to_linear(c) -> np.ndarray:
    """The sRGB transfer function inverted (IEC 61966-2-1), float64."""
    c = np.clip(np.asarray(c, np.float64), 0.0, 1.0)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(c) -> np.ndarray:
    """The sRGB transfer function (IEC 61966-2-1), float64."""
    c = np.clip(np.asarray(c, np.float64), 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1.0 / 2.4) - 0.055)


def _pad(data: bytes, fill: bytes) -> bytes:
    return data + fill * (-len(data) % 4)


def encode_glb(positions, triangles, colors, extras=None) -> bytes:
    """GLB bytes of the mesh ``positions`` [N, 3] (as they are written), ``triangles`` [M, 3] and
    sRGB ``colors`` [N, 3] in [0, 1] (written linear), with ``extras`` in ``asset.extras``."""
    pos = np.ascontiguousarray(positions, "<f4").reshape(-1, 3)
    idx = np.ascontiguousarray(triangles, "<u4").reshape(-1)
    col = np.ascontiguousarray(srgb_to_linear(colors), "<f4").reshape(-1, 3)
    parts = [idx.tobytes(), pos.tobytes(), col.tobytes()]
    views, offset = [], 0
    for k, part in enumerate(parts):
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": len(part),
                      "target": 34963 if k == 0 else 34962})
        offset += len(part) + (-len(part) % 4)
    blob = b"".join(_pad(p, b"\0") for p in parts)
    lo, hi = (pos.min(0), pos.max(0)) if len(pos) else (np.zeros(3), np.zeros(3))
    tree = {
        "asset": {"version": "2.0", "generator": "tsplus-wgpu", **({"extras": extras} if extras else {})},
        "extensionsUsed": ["KHR_materials_unlit"],
        "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"name": "tsplus_mesh", "mesh": 0}],
        "meshes": [{"name": "tsplus_mesh", "primitives": [
            {"attributes": {"POSITION": 1, "COLOR_0": 2}, "indices": 0, "material": 0, "mode": 4}]}],
        "materials": [{"name": "vertex colours, unlit", "doubleSided": True,
                       "pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0], "metallicFactor": 0.0,
                                                "roughnessFactor": 1.0},
                       "extensions": {"KHR_materials_unlit": {}}}],
        "accessors": [
            {"bufferView": 0, "componentType": 5125, "count": int(idx.size), "type": "SCALAR"},
            {"bufferView": 1, "componentType": 5126, "count": len(pos), "type": "VEC3",
             "min": [float(v) for v in lo], "max": [float(v) for v in hi]},
            {"bufferView": 2, "componentType": 5126, "count": len(col), "type": "VEC3"}],
        "bufferViews": views,
        "buffers": [{"byteLength": len(blob)}],
    }
    text = _pad(json.dumps(tree, separators=(",", ":")).encode(), b" ")
    total = 12 + 8 + len(text) + 8 + len(blob)
    return (struct.pack("<III", _GLB_MAGIC, 2, total) + struct.pack("<II", len(text), _JSON) + text
            + struct.pack("<II", len(blob), _BIN) + blob)


def json_chunk_length(head: bytes) -> int | None:
    """The byte length of the JSON chunk of a GLB that starts with ``head`` (its first 20 bytes at
    least), or None when ``head`` is not the start of a GLB."""
    if len(head) < 20:
        return None
    magic, _, _ = struct.unpack_from("<III", head, 0)
    n, kind = struct.unpack_from("<II", head, 12)
    return n if magic == _GLB_MAGIC and kind == _JSON else None


def glb_colors(data: bytes) -> np.ndarray | None:
    """sRGB ``[N, 3]`` of the first primitive's ``COLOR_0`` in the GLB ``data`` (linear by the
    specification; floats, normalised bytes or shorts; RGB or RGBA), or None where it has none or
    is not a GLB this reads (sparse accessors, several buffers, other component types)."""
    try:
        n = json_chunk_length(data)
        if n is None:
            return None
        tree = json.loads(data[20:20 + n])
        at = 20 + n
        blen, bkind = struct.unpack_from("<II", data, at)
        if bkind != _BIN:
            return None
        blob = memoryview(data)[at + 8:at + 8 + blen]
        acc = tree["accessors"][tree["meshes"][0]["primitives"][0]["attributes"]["COLOR_0"]]
        view = tree["bufferViews"][acc["bufferView"]]
        dtype, norm = _COMPONENTS[acc["componentType"]]
        width = {"VEC3": 3, "VEC4": 4}[acc["type"]]
        if view.get("buffer", 0) != 0 or "sparse" in acc:
            return None
        item = np.dtype(dtype).itemsize
        stride = view.get("byteStride") or item * width
        start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
        count = int(acc["count"])
        raw = np.ndarray((count, width), dtype, buffer=blob, offset=start, strides=(stride, item))
        lin = raw[:, :3].astype(np.float64) / (norm or 1.0)
        return linear_to_srgb(lin)
    except (KeyError, IndexError, TypeError, ValueError, struct.error):
        return None
