"""The wgpu runtime: adapter choice, device with WebGPU default limits, feature
detection, the WGSL loader with ``#import``, reflection of bindings and uniform
structs from the WGSL source, and the pipeline cache.

The WGSL files are the single source of truth: binding slots and uniform-struct
layouts are read out of them, so host and shader cannot drift apart.
"""

from __future__ import annotations

import os
import re
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

# lavapipe prints a warning on every start when this is unset.
if not os.environ.get("XDG_RUNTIME_DIR"):
    _rt = Path(tempfile.gettempdir()) / f"tsplus-runtime-{os.getuid() if hasattr(os, 'getuid') else 0}"
    _rt.mkdir(mode=0o700, exist_ok=True)
    os.environ["XDG_RUNTIME_DIR"] = str(_rt)

import wgpu  # noqa: E402

LAVAPIPE_HINT = (
    "no Vulkan adapter found: install a Vulkan driver for your GPU, or the CPU driver lavapipe "
    "(Debian/Ubuntu: `apt-get install -y mesa-vulkan-drivers`; Fedora: `dnf install mesa-vulkan-drivers`)"
)

#: The WebGPU default limits. The device is created with exactly these unless a
#: larger limit is asked for and the adapter has it.
WEBGPU_DEFAULT_LIMITS = {
    "max-texture-dimension-1d": 8192,
    "max-texture-dimension-2d": 8192,
    "max-texture-dimension-3d": 2048,
    "max-texture-array-layers": 256,
    "max-bind-groups": 4,
    "max-bindings-per-bind-group": 1000,
    "max-dynamic-uniform-buffers-per-pipeline-layout": 8,
    "max-dynamic-storage-buffers-per-pipeline-layout": 4,
    "max-sampled-textures-per-shader-stage": 16,
    "max-samplers-per-shader-stage": 16,
    "max-storage-buffers-per-shader-stage": 8,
    "max-storage-textures-per-shader-stage": 4,
    "max-uniform-buffers-per-shader-stage": 12,
    "max-uniform-buffer-binding-size": 65536,
    "max-storage-buffer-binding-size": 134217728,
    "min-uniform-buffer-offset-alignment": 256,
    "min-storage-buffer-offset-alignment": 256,
    "max-vertex-buffers": 8,
    "max-buffer-size": 268435456,
    "max-vertex-attributes": 16,
    "max-vertex-buffer-array-stride": 2048,
    "max-inter-stage-shader-variables": 16,
    "max-color-attachments": 8,
    "max-color-attachment-bytes-per-sample": 32,
    "max-compute-workgroup-storage-size": 16384,
    "max-compute-invocations-per-workgroup": 256,
    "max-compute-workgroup-size-x": 256,
    "max-compute-workgroup-size-y": 256,
    "max-compute-workgroup-size-z": 64,
    "max-compute-workgroups-per-dimension": 65535,
}

_TYPE_RANK = {"DiscreteGPU": 0, "IntegratedGPU": 1, "VirtualGPU": 2, "CPU": 3, "Unknown": 4}
_ALIASES = {"lavapipe": "llvmpipe", "cpu": "llvmpipe"}


class NoAdapterError(RuntimeError):
    """No usable GPU adapter (the message says how to get one)."""


def _find_shader_dir() -> Path:
    here = Path(__file__).resolve().parent
    for cand in (here / "shaders", here.parent / "shaders"):
        if (cand / "common").is_dir():
            return cand
    raise FileNotFoundError(f"shaders/ not found next to {here}; reinstall the package")


SHADER_DIR = _find_shader_dir()


def adapter_description(adapter) -> str:
    info = adapter.info
    return f"{info.get('device', '?')} ({info.get('adapter_type', '?')}, {info.get('backend_type', '?')})"


def list_adapters(vulkan_only=True):
    """All adapters wgpu sees, best first (discrete > integrated > virtual > CPU)."""
    adapters = list(wgpu.gpu.enumerate_adapters_sync())
    if vulkan_only and os.environ.get("TSPLUS_ANY_BACKEND", "") != "1":
        vk = [a for a in adapters if a.info.get("backend_type") == "Vulkan"]
        # Outside Linux (Metal, D3D12) fall back to what the platform offers.
        if vk or os.name == "posix" and not os.uname().sysname == "Darwin":
            adapters = vk
    adapters.sort(key=lambda a: _TYPE_RANK.get(a.info.get("adapter_type", "Unknown"), 4))
    return adapters


def select_adapter(name=None):
    """Pick an adapter. ``name`` (or ``TSPLUS_ADAPTER``) is matched, case-insensitively,
    against the adapter's device, vendor, description and type; ``lavapipe`` and ``cpu``
    select Mesa's llvmpipe. Without a name the best adapter wins (discrete first)."""
    name = name or os.environ.get("TSPLUS_ADAPTER") or None
    adapters = list_adapters()
    if not adapters:
        raise NoAdapterError(LAVAPIPE_HINT)
    if name is None:
        return adapters[0]
    want = _ALIASES.get(name.lower(), name.lower())
    for a in adapters:
        info = a.info
        text = " ".join(str(info.get(k, "")) for k in ("device", "vendor", "description", "adapter_type")).lower()
        if want in text:
            return a
    names = ", ".join(adapter_description(a) for a in adapters)
    raise NoAdapterError(f"--adapter/TSPLUS_ADAPTER {name!r} matches no adapter; available: {names}")


@dataclass
class Features:
    timestamps: bool = False
    float32_atomics: bool = False
    subgroups: bool = False


class GpuContext:
    """One adapter + device, with WebGPU default limits and optional features.

    Args:
        adapter: an adapter, a name to match (see :func:`select_adapter`) or None.
        limits: larger limits to request, e.g. ``{"max-buffer-size": 2**30}``; each is
            checked against the adapter and refused with a ValueError when unavailable.
        poison: fill every new scratch/output buffer with 0xFF bytes (NaN as float, 2^32-1
            as u32) to catch kernels that rely on zero-initialised memory; also on with
            ``TSPLUS_POISON=1``. For tests and debugging.
    """

    def __init__(self, adapter=None, limits=None, poison=None):
        self.poison = (os.environ.get("TSPLUS_POISON") == "1") if poison is None else bool(poison)
        if adapter is None or isinstance(adapter, str):
            adapter = select_adapter(adapter)
        self.adapter = adapter
        self.info = dict(adapter.info)
        available = dict(adapter.limits)
        req = dict(WEBGPU_DEFAULT_LIMITS)
        for k, v in (limits or {}).items():
            k = k.replace("_", "-")
            if k not in available:
                raise ValueError(f"limits: unknown limit {k!r}")
            if v > available[k]:
                raise ValueError(f"limits: {k}={v} requested but the adapter offers only {available[k]}")
            req[k] = v
        # Never ask for more than the adapter has (some drivers offer less than WebGPU's defaults).
        for k in list(req):
            if k in available:
                if k.startswith("min-"):
                    req[k] = max(req[k], available[k])
                else:
                    req[k] = min(req[k], available[k])
            else:
                del req[k]
        feats = set(adapter.features)
        self.features = Features(
            timestamps="timestamp-query" in feats,
            float32_atomics="shader-float32-atomic" in feats,
            subgroups="subgroup" in feats,
        )
        required = []
        if self.features.timestamps and os.environ.get("TSPLUS_NO_TIMESTAMPS") != "1":
            required.append("timestamp-query")
        else:
            self.features.timestamps = False
        self.device = adapter.request_device_sync(required_features=required, required_limits=req)
        self.limits = {k: v for k, v in dict(self.device.limits).items()}
        self.queue = self.device.queue
        self._pipelines = {}
        self._sources = {}

    @property
    def name(self):
        return adapter_description(self.adapter)

    @property
    def is_cpu(self):
        return self.info.get("adapter_type") == "CPU"

    # ---------------------------------------------------------------- buffers
    def check_size(self, name, nbytes):
        lim = self.limits["max-storage-buffer-binding-size"]
        if nbytes > lim:
            raise ValueError(
                f"{name}: needs {nbytes / 2**20:.1f} MiB in one buffer, over this device's "
                f"storage-binding limit of {lim / 2**20:.0f} MiB; use fewer triangles or a smaller image")

    def buffer(self, nbytes, label="", usage=None):
        usage = usage if usage is not None else (
            wgpu.BufferUsage.STORAGE | wgpu.BufferUsage.COPY_SRC | wgpu.BufferUsage.COPY_DST)
        # zero-sized buffers are invalid; whole vec4s so any buffer can be read 16 bytes at a time
        nbytes = max(16, (int(nbytes) + 15) // 16 * 16)
        self.check_size(label or "buffer", nbytes)
        buf = self.device.create_buffer(size=nbytes, usage=usage, label=label)
        if self.poison and usage & wgpu.BufferUsage.COPY_DST:
            self.queue.write_buffer(buf, 0, b"\xff" * nbytes)
        return buf

    def upload(self, array, label="", usage=None):
        arr = np.ascontiguousarray(array)
        if arr.nbytes == 0:
            arr = np.zeros(4, np.uint32)
        self.check_size(label or "buffer", arr.nbytes)
        usage = usage if usage is not None else (
            wgpu.BufferUsage.STORAGE | wgpu.BufferUsage.COPY_SRC | wgpu.BufferUsage.COPY_DST)
        if arr.nbytes % 16:   # whole vec4s (see buffer())
            arr = np.concatenate([arr.view(np.uint8).ravel(), np.zeros(16 - arr.nbytes % 16, np.uint8)])
        return self.device.create_buffer_with_data(data=arr, usage=usage, label=label)

    def uniform(self, struct_value, label=""):
        return self.device.create_buffer_with_data(
            data=struct_value.tobytes(), usage=wgpu.BufferUsage.UNIFORM | wgpu.BufferUsage.COPY_DST, label=label)

    def read(self, buffer, dtype, count=None, offset=0):
        dtype = np.dtype(dtype)
        size = None if count is None else int(count) * dtype.itemsize
        if size == 0:
            return np.zeros(0, dtype)
        data = self.queue.read_buffer(buffer, offset, size)
        return np.frombuffer(data, dtype=dtype).copy()

    def wait(self):
        """Block until all submitted work is done (a 4-byte readback through the queue;
        wgpu-py 0.32's on_submitted_work_done is broken)."""
        if not hasattr(self, "_fence"):
            self._fence = self.buffer(16, "fence")
        self.queue.read_buffer(self._fence, 0, 4)

    # ---------------------------------------------------------------- shaders
    def source(self, stage):
        if stage not in self._sources:
            self._sources[stage] = load_wgsl(stage)
        return self._sources[stage]

    def pipeline(self, stage, constants=None):
        """Compiled compute pipeline for ``shaders/<stage>.wgsl``, cached by stage + constants."""
        key = (stage, tuple(sorted((constants or {}).items())))
        if key not in self._pipelines:
            src = self.source(stage)
            try:
                module = self.device.create_shader_module(code=src.code, label=stage)
                bgl = self.device.create_bind_group_layout(entries=src.layout_entries())
                layout = self.device.create_pipeline_layout(bind_group_layouts=[bgl])
                compute = {"module": module, "entry_point": "main"}
                if constants:
                    compute["constants"] = dict(constants)
                pipe = self.device.create_compute_pipeline(layout=layout, compute=compute, label=stage)
            except Exception as exc:
                raise RuntimeError(f"shader {stage}.wgsl failed to compile: {exc}") from exc
            self._pipelines[key] = (pipe, bgl, src)
        return self._pipelines[key]


# -------------------------------------------------------------------- WGSL loading

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
    kind: str  # "uniform", "storage", "read-only-storage"
    type: str


@dataclass
class WgslSource:
    stage: str
    code: str
    bindings: dict = field(default_factory=dict)  # name -> Binding
    structs: dict = field(default_factory=dict)   # name -> np.dtype

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


def load_wgsl(stage) -> WgslSource:
    path = SHADER_DIR / f"{stage}.wgsl"
    if not path.is_file():
        raise FileNotFoundError(f"shader {path} does not exist")
    code = resolve_imports(path.read_text())
    clean = _strip_comments(code)
    src = WgslSource(stage=stage, code=code)
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
    return sorted(p.stem for p in SHADER_DIR.glob("*.wgsl"))


# -------------------------------------------------------------------- dispatch


def grid(groups, max_dim=65535):
    """Split a 1-D workgroup count into a 2-D grid within the per-dimension limit."""
    groups = max(1, int(groups))
    if groups <= max_dim:
        return (groups, 1, 1)
    y = (groups + max_dim - 1) // max_dim
    x = (groups + y - 1) // y
    return (x, y, 1)


class Stage:
    """Owns the pipeline of one ``shaders/<stage>.wgsl`` and dispatches it with buffers
    bound by name. Subclasses set ``stage`` and give ``__call__`` a typed signature."""

    stage = ""

    def __init__(self, ctx: GpuContext, constants=None):
        self.ctx = ctx
        self.pipeline, self.layout, self.src = ctx.pipeline(self.stage, constants)

    def uniform(self, struct_name, **values):
        dt = self.src.structs[struct_name]
        arr = np.zeros((), dt)
        for k, v in values.items():
            if k not in dt.names:
                raise KeyError(f"{self.stage}.wgsl: struct {struct_name} has no field {k}")
            arr[k] = v
        missing = [n for n in dt.names if n not in values and not n.startswith("_")]
        if missing:
            raise KeyError(f"{self.stage}.wgsl: struct {struct_name} fields not set: {missing}")
        return self.ctx.uniform(arr, label=f"{self.stage}.{struct_name}")

    def bind(self, buffers):
        want = set(self.src.bindings)
        got = set(buffers)
        if want != got:
            raise KeyError(f"{self.stage}.wgsl bindings: missing {sorted(want - got)}, unexpected {sorted(got - want)}")
        entries = [{"binding": self.src.bindings[n].slot, "resource": {"buffer": buf, "offset": 0, "size": buf.size}}
                   for n, buf in buffers.items()]
        return self.ctx.device.create_bind_group(layout=self.layout, entries=entries)

    def dispatch(self, encoder, groups, buffers, profiler=None, label=None):
        """Record one dispatch; ``groups`` is an int (split into a 2-D grid) or an (x, y, z) tuple."""
        bg = self.bind(buffers)
        if isinstance(groups, int):
            groups = grid(groups, self.ctx.limits["max-compute-workgroups-per-dimension"])
        tw = profiler.writes(label or self.stage) if profiler is not None else None
        cp = encoder.begin_compute_pass(timestamp_writes=tw) if tw else encoder.begin_compute_pass()
        cp.set_pipeline(self.pipeline)
        cp.set_bind_group(0, bg)
        cp.dispatch_workgroups(*groups)
        cp.end()


class Profiler:
    """Per-stage GPU time from timestamp queries (summed over a stage's dispatches)."""

    def __init__(self, ctx: GpuContext, capacity=512):
        if not ctx.features.timestamps:
            raise RuntimeError("timestamp queries are not available on this device")
        self.ctx = ctx
        self.capacity = capacity
        self.qs = ctx.device.create_query_set(type="timestamp", count=capacity)
        self.labels = []

    def writes(self, label):
        i = len(self.labels)
        if 2 * i + 2 > self.capacity:
            return None
        self.labels.append(label)
        return {"query_set": self.qs, "beginning_of_pass_write_index": 2 * i,
                "end_of_pass_write_index": 2 * i + 1}

    def resolve(self):
        """Returns {label: milliseconds}. Call after the work has been submitted."""
        n = 2 * len(self.labels)
        if n == 0:
            return {}
        buf = self.ctx.device.create_buffer(size=8 * n, usage=wgpu.BufferUsage.QUERY_RESOLVE | wgpu.BufferUsage.COPY_SRC)
        enc = self.ctx.device.create_command_encoder()
        enc.resolve_query_set(self.qs, 0, n, buf, 0)
        self.ctx.queue.submit([enc.finish()])
        ts = self.ctx.read(buf, np.uint64)
        out = {}
        for i, label in enumerate(self.labels):
            out[label] = out.get(label, 0.0) + max(0, int(ts[2 * i + 1]) - int(ts[2 * i])) * 1e-6
        self.labels = []
        return out


def host_time(ctx: GpuContext, fn):
    """Run ``fn()`` (which submits work) and wait for the device; returns seconds."""
    ctx.wait()
    t0 = time.perf_counter()
    fn()
    ctx.wait()
    return time.perf_counter() - t0
