"""The WGSL loader: ``#import`` resolution over ``shaders/common/``, reflection of bindings,
uniform structs, constants and workgroup sizes from the source, so host and shader cannot
drift apart. Kernel K lives in ``shaders/<group>/K.wgsl``; names are unique across groups."""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import wgpu


def _find_shader_dir() -> Path:
    here = Path(__file__).resolve().parent.parent      # the package folder
    for cand in (here / "shaders", here.parent / "shaders"):
        if (cand / "common").is_dir():
            return cand
    raise FileNotFoundError(f"shaders/ not found next to {here}; reinstall the package")


SHADER_DIR = _find_shader_dir()


_IMPORT_RE = re.compile(r"^\s*#import\s+([\w/]+)\s*$", re.M)


_BINDING_RE = re.compile(
    r"@group\(\s*(\d+)\s*\)\s*@binding\(\s*(\d+)\s*\)\s*var\s*(<[^>]*>)?\s*(\w+)\s*:\s*([^;]+);")


_STRUCT_RE = re.compile(r"struct\s+(\w+)\s*\{([^}]*)\}", re.S)


# (size, align) of the WGSL host-shareable scalar and vector types
_WGSL_TYPES = {
    "f32": (4, 4, "<f4", ()), "u32": (4, 4, "<u4", ()), "i32": (4, 4, "<i4", ()),
    "vec2<f32>": (8, 8, "<f4", (2,)), "vec2<u32>": (8, 8, "<u4", (2,)), "vec2<i32>": (8, 8, "<i4", (2,)),
    "vec3<f32>": (12, 16, "<f4", (3,)), "vec3<u32>": (12, 16, "<u4", (3,)), "vec3<i32>": (12, 16, "<i4", (3,)),
    "vec4<f32>": (16, 16, "<f4", (4,)), "vec4<u32>": (16, 16, "<u4", (4,)), "vec4<i32>": (16, 16, "<i4", (4,)),
    "vec2f": (8, 8, "<f4", (2,)), "vec3f": (12, 16, "<f4", (3,)), "vec4f": (16, 16, "<f4", (4,)),
    "vec2u": (8, 8, "<u4", (2,)), "vec4u": (16, 16, "<u4", (4,)), "vec4i": (16, 16, "<i4", (4,)),
    "mat4x4<f32>": (64, 16, "<f4", (16,)), "mat4x4f": (64, 16, "<f4", (16,)),   # column-major, 16 floats
}


def resolve_imports(text, seen=None):
    """Inline ``#import name`` lines (``shaders/common/name.wgsl``), each file once."""
    seen = set() if seen is None else seen

    def sub(m):
        name = m.group(1)
        if name in seen:
            return ""
        seen.add(name)
        path = SHADER_DIR / "common" / f"{name}.wgsl"
        if not path.is_file():
            raise FileNotFoundError(f"#import {name}: {path} does not exist")
        return f"// ---- begin import {name}\n" + resolve_imports(path.read_text(), seen) + f"// ---- end import {name}\n"

    return _IMPORT_RE.sub(sub, text)


def _strip_comments(text):
    return re.sub(r"//[^\n]*", "", text)


@dataclass
class Binding:
    group: int
    slot: int
    name: str
    kind: str  # "uniform", "storage", "read-only-storage" (render pipelines also "texture", "sampler")
    type: str


@dataclass
class WgslSource:
    stage: str
    code: str
    bindings: dict = field(default_factory=dict)  # name -> Binding
    structs: dict = field(default_factory=dict)   # name -> np.dtype
    constants: dict = field(default_factory=dict)  # name -> int | float (module-scope scalar ``const``)
    overrides: dict = field(default_factory=dict)  # name -> default value (None without one)
    workgroup_size: tuple = (1, 1, 1)              # of the entry point ``main``

    @property
    def invocations(self):
        """Invocations per workgroup of ``main``."""
        x, y, z = self.workgroup_size
        return x * y * z

    def const(self, name):
        """A module-scope scalar ``const`` (or an ``override``'s default) of this shader."""
        if name in self.constants:
            return self.constants[name]
        if self.overrides.get(name) is not None:
            return self.overrides[name]
        raise KeyError(f"{self.stage}.wgsl has no scalar const {name}")

    def layout_entries(self):
        entries = []
        for b in sorted(self.bindings.values(), key=lambda b: b.slot):
            entries.append({"binding": b.slot, "visibility": wgpu.ShaderStage.COMPUTE,
                            "buffer": {"type": b.kind}})
        return entries


def struct_dtype(body, structs):
    """numpy structured dtype laid out by WGSL's host-shareable rules."""
    names, formats, offsets = [], [], []
    off, max_align = 0, 4
    for line in _strip_comments(body).split(","):
        line = line.strip()
        if not line:
            continue
        fname, ftype = (s.strip() for s in line.split(":", 1))
        ftype = ftype.replace(" ", "")
        if ftype in _WGSL_TYPES:
            size, align, base, shape = _WGSL_TYPES[ftype]
            fmt = (base, shape) if shape else base
        elif ftype in structs:
            sub = structs[ftype]
            size, align, fmt = sub.itemsize, sub.metadata["align"], sub
        else:
            raise ValueError(f"WGSL struct field {fname}: unsupported type {ftype}")
        off = (off + align - 1) // align * align
        names.append(fname)
        formats.append(fmt)
        offsets.append(off)
        off += size
        max_align = max(max_align, align)
    itemsize = (off + max_align - 1) // max_align * max_align
    dt = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": itemsize})
    return np.dtype(dt, metadata={"align": max_align})


_CONST_RE = re.compile(r"^\s*(const|override)\s+(\w+)\s*(?::\s*(\w+))?\s*(?:=\s*([^;]+))?;", re.M)
_WORKGROUP_RE = re.compile(r"@workgroup_size\s*\(([^)]*)\)\s*fn\s+main\b")
_LITERAL_RE = re.compile(r"\b(0x[0-9a-fA-F]+|\d+\.?\d*(?:[eE][+-]?\d+)?|\.\d+(?:[eE][+-]?\d+)?)[uif]?\b")


def _scalar(expr, known, typ=None):
    """Value of a WGSL scalar constant expression over numeric literals, earlier constants,
    + - * / % << >> and parentheses; None when it is anything else (arrays, vectors, calls)."""
    expr = expr.strip()
    if re.search(r"[\[\]{}]|\w\s*\(|\(\s*\)|<[a-z]", expr):
        return None
    py = _LITERAL_RE.sub(lambda m: m.group(1), expr)
    if not re.fullmatch(r"[\w\s.+\-*/%()<>]*", py):
        return None
    try:
        value = eval(py, {"__builtins__": {}}, dict(known))  # noqa: S307  (digits, names, operators only)
    except Exception:
        return None
    if typ in ("u32", "i32") or (typ is None and isinstance(value, int)):
        if isinstance(value, float):
            if not value.is_integer():
                return None
            value = int(value)
        return value
    return float(value)


def reflect_constants(code):
    """(constants, overrides) of WGSL source: module-scope scalar ``const`` and ``override``
    declarations, evaluated in order (later ones may use earlier ones)."""
    consts, overrides = {}, {}
    for m in _CONST_RE.finditer(_strip_comments(code)):
        kind, name, typ, expr = m.groups()
        value = None if expr is None else _scalar(expr, {**consts, **{k: v for k, v in overrides.items()
                                                                       if v is not None}}, typ)
        if kind == "override":
            overrides[name] = value
        elif value is not None:
            consts[name] = value
    return consts, overrides


def reflect_workgroup_size(code, known):
    """The ``@workgroup_size`` of ``fn main`` as (x, y, z); its arguments may be constants."""
    m = _WORKGROUP_RE.search(_strip_comments(code))
    if not m:
        return (1, 1, 1)
    dims = []
    for arg in m.group(1).split(","):
        if not arg.strip():
            continue
        v = _scalar(arg, known, "u32")
        if v is None:
            raise ValueError(f"@workgroup_size({m.group(1)}): {arg.strip()!r} is not a constant expression")
        dims.append(int(v))
    return tuple(dims + [1] * (3 - len(dims)))


@functools.lru_cache(maxsize=None)        # shader files do not change while we run: parse each once
def constant(name, kernel="frame"):
    """A WGSL constant as Python reads it: from ``shaders/common/<kernel>.wgsl`` when such a
    file exists, else from kernel ``kernel`` (with its imports)."""
    common = SHADER_DIR / "common" / f"{kernel}.wgsl"
    code = resolve_imports(common.read_text()) if common.is_file() else load_wgsl(kernel).code
    consts, overrides = reflect_constants(code)
    if name in consts:
        return consts[name]
    if overrides.get(name) is not None:
        return overrides[name]
    raise KeyError(f"{kernel}.wgsl has no scalar const {name}")


def shader_path(stage) -> Path:
    """``shaders/<group>/<stage>.wgsl`` for a kernel name (unique across groups), or the
    file ``shaders/<stage>.wgsl`` for a ``group/name`` path."""
    if "/" in stage:
        path = SHADER_DIR / f"{stage}.wgsl"
        if not path.is_file():
            raise FileNotFoundError(f"shader {path} does not exist")
        return path
    found = [p for p in SHADER_DIR.glob(f"*/{stage}.wgsl") if p.parent.name != "common"]
    if len(found) != 1:
        raise FileNotFoundError(f"shader {stage}.wgsl: {'not found' if not found else 'in several groups'} "
                                f"under {SHADER_DIR}")
    return found[0]


def kernel_group(stage) -> str:
    """The group (folder under ``shaders/``) of a kernel."""
    return shader_path(stage).parent.name


def load_wgsl(stage) -> WgslSource:
    path = shader_path(stage)
    code = resolve_imports(path.read_text())
    clean = _strip_comments(code)
    src = WgslSource(stage=stage, code=code)
    src.constants, src.overrides = reflect_constants(code)
    src.workgroup_size = reflect_workgroup_size(code, {**src.constants, **{
        k: v for k, v in src.overrides.items() if v is not None}})
    for m in _STRUCT_RE.finditer(clean):
        try:
            src.structs[m.group(1)] = struct_dtype(m.group(2), src.structs)
        except ValueError:
            pass  # structs holding atomics or arrays are not host-shared
    for m in _BINDING_RE.finditer(clean):
        group, slot, space, name, typ = int(m.group(1)), int(m.group(2)), m.group(3) or "", m.group(4), m.group(5)
        space = space.replace(" ", "")
        if group != 0:
            raise ValueError(f"{stage}.wgsl: only @group(0) is used (binding {name})")
        if space.startswith("<uniform"):
            kind = "uniform"
        elif space.startswith("<storage") and "read_write" in space:
            kind = "storage"
        elif space.startswith("<storage"):
            kind = "read-only-storage"
        elif not space and typ.strip().startswith(("texture_", "sampler")):
            kind = "texture" if typ.strip().startswith("texture_") else "sampler"   # render pipelines
        else:
            raise ValueError(f"{stage}.wgsl: binding {name} has unsupported address space {space}")
        if name in src.bindings:
            raise ValueError(f"{stage}.wgsl: binding name {name} used twice")
        src.bindings[name] = Binding(group, slot, name, kind, typ.strip())
    slots = sorted(b.slot for b in src.bindings.values())
    if slots != list(range(len(slots))):
        raise ValueError(f"{stage}.wgsl: binding slots must be 0..n-1 without gaps, got {slots}")
    return src


def all_stages():
    """Every compute kernel's name (``shaders/<group>/*.wgsl`` except ``common/`` and the
    render pipelines in ``mesh/``)."""
    return sorted(p.stem for p in SHADER_DIR.glob("*/*.wgsl") if p.parent.name not in ("common", "mesh"))
