"""The wgpu runtime: adapter choice, device with WebGPU default limits (the two size limits
raised to what the adapter offers, :data:`SIZE_LIMITS`), feature detection, the WGSL loader
with ``#import``, reflection of bindings and uniform structs from the WGSL source, and the
pipeline cache.

The WGSL files are the single source of truth: binding slots and uniform-struct
layouts are read out of them, so host and shader cannot drift apart.
"""

from __future__ import annotations

import os
import tempfile
import weakref
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from .bindings import BindGroupCache, UniformCache
from .wgsl import load_wgsl

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

#: The limits that decide how large a model, an image and their scratch may grow. A device asks
#: the adapter for as much of these as it offers (capped at :data:`SIZE_LIMIT_CAP`), unless it is
#: made with ``limits="webgpu"`` or ``TSPLUS_WEBGPU_LIMITS=1``: llvmpipe offers 128 MiB per
#: binding (the default) and 2 GiB per buffer, an NVIDIA H100 at least the cap. Everything that
#: sizes a model or an image reads the device's limits, so a larger binding is used where offered.
SIZE_LIMITS = ("max-storage-buffer-binding-size", "max-buffer-size")
#: 2 GiB less 256 bytes: a byte offset into any buffer fits a signed 32-bit integer
SIZE_LIMIT_CAP = 2**31 - 256

_TYPE_RANK = {"DiscreteGPU": 0, "IntegratedGPU": 1, "VirtualGPU": 2, "CPU": 3, "Unknown": 4}
_ALIASES = {"lavapipe": "llvmpipe", "cpu": "llvmpipe"}


class NoAdapterError(RuntimeError):
    """No usable GPU adapter (the message says how to get one)."""


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


def adapter_size_limits(available):
    """The :data:`SIZE_LIMITS` a device asks an adapter with limits ``available`` for: as much as
    it offers, at most :data:`SIZE_LIMIT_CAP`, in whole 256 bytes, no binding larger than a buffer."""
    out = {k: min(int(available.get(k, WEBGPU_DEFAULT_LIMITS[k])), SIZE_LIMIT_CAP) // 256 * 256
           for k in SIZE_LIMITS}
    out["max-storage-buffer-binding-size"] = min(out["max-storage-buffer-binding-size"], out["max-buffer-size"])
    return out


#: the blend kernels' layouts (``GpuContext.layout``): each pass's kernel, ``"column"`` (16
#: invocations a 16x16 tile, a column of 16 pixels each, for CPU drivers) or ``"pixel"`` (256
#: invocations, one pixel each). ``gpu`` pairs the pixel forward with the column backward: on an
#: NVIDIA H100 the pixel forward blend is 4x faster than the column one, the pixel backward 2.3-3.3x
#: slower (docs/measurements.md, the third GPU session); ``pixel`` keeps both pixel kernels.
LAYOUT_KERNELS = {"cpu": {"forward": "column", "backward": "column"},
                  "gpu": {"forward": "pixel", "backward": "column"},
                  "pixel": {"forward": "pixel", "backward": "pixel"}}
LAYOUTS = tuple(LAYOUT_KERNELS)


def layout_kernel(layout, which) -> str:
    """The blend kernel (``"column"`` or ``"pixel"``) of pass ``which`` (``"forward"`` or
    ``"backward"``) in ``layout``."""
    return LAYOUT_KERNELS[layout][which]


def choose_layout(info, layout=None):
    """``layout`` if given, else ``TSPLUS_LAYOUT``, else ``"cpu"`` for a CPU adapter (by its
    ``info["adapter_type"]``) and ``"gpu"`` for any other."""
    source = "layout"
    if layout is None:
        layout, source = os.environ.get("TSPLUS_LAYOUT") or None, "TSPLUS_LAYOUT"
    if layout is None:
        return "cpu" if info.get("adapter_type") == "CPU" else "gpu"
    if layout not in LAYOUTS:
        raise ValueError(f"{source}: expected one of {', '.join(LAYOUTS)}, got {layout!r}")
    return layout


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
            checked against the adapter and refused with a ValueError when unavailable. The
            :data:`SIZE_LIMITS` not named here are the adapter's own (at most
            :data:`SIZE_LIMIT_CAP`); ``"webgpu"`` (or ``TSPLUS_WEBGPU_LIMITS=1``) keeps every
            limit at WebGPU's default instead.
        poison: fill every new scratch/output buffer with 0xFF bytes (NaN as float, 2^32-1
            as u32) to catch kernels that rely on zero-initialised memory; also on with
            ``TSPLUS_POISON=1``. For tests and debugging.
        layout: the blend kernels' layout (:data:`LAYOUT_KERNELS`): ``"cpu"`` (the column kernels
            for CPU drivers: 8 invocations a tile of two 16-pixel columns each in the forward, 16
            of one column in the backward), ``"gpu"`` (one invocation a pixel in the
            forward, the column backward) or ``"pixel"`` (one invocation a pixel in both);
            default ``TSPLUS_LAYOUT`` or, unset, the adapter's class (``"cpu"`` on a CPU adapter).
    """

    def __init__(self, adapter=None, limits=None, poison=None, layout=None):
        self.poison = (os.environ.get("TSPLUS_POISON") == "1") if poison is None else bool(poison)
        if adapter is None or isinstance(adapter, str):
            adapter = select_adapter(adapter)
        self.adapter = adapter
        self.info = dict(adapter.info)
        self.layout = choose_layout(self.info, layout)
        available = dict(adapter.limits)
        req = dict(WEBGPU_DEFAULT_LIMITS)
        if limits == "webgpu" or os.environ.get("TSPLUS_WEBGPU_LIMITS") == "1":
            limits = dict(limits) if isinstance(limits, dict) else {}
        else:
            limits = {**adapter_size_limits(available), **(limits or {})}
        for k, v in limits.items():
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
        self._bytes = [0, 0]      # [live, peak] bytes of the buffers made here (_tally)
        # the host's work kept between dispatches: uniform buffers by content, bind groups by
        # their buffers (gpu/bindings.py), the training step's forward and backward buffers,
        # one submit for the backward's stages. TSPLUS_HOST_CACHING=0 (or host_caching =
        # False) does all of it anew every time, as before 2026-11-27 (tsplus bench-step)
        self.host_caching = os.environ.get("TSPLUS_HOST_CACHING", "1") != "0"
        self._uniforms = UniformCache(self._make_uniform)
        self._bind_groups = BindGroupCache(self.device)

    @property
    def name(self):
        return adapter_description(self.adapter)

    @property
    def is_cpu(self):
        return self.info.get("adapter_type") == "CPU"

    # ---------------------------------------------------------------- buffers
    def check_size(self, name, nbytes, chunked=False):
        """Raise the one-line error for a buffer of ``nbytes`` over this device's storage-binding
        limit, or with ``chunked`` (bound a range at a time: :mod:`.chunks`) its buffer-size limit."""
        key = "max-buffer-size" if chunked else "max-storage-buffer-binding-size"
        lim = self.limits[key]
        if nbytes > lim:
            what = "buffer-size" if chunked else "storage-binding"
            raise ValueError(
                f"{name}: needs {nbytes / 2**20:.1f} MiB in one buffer, over this device's "
                f"{what} limit of {lim / 2**20:.0f} MiB; use fewer triangles or a smaller image")

    def buffer(self, nbytes, label="", usage=None, chunked=False):
        """A new buffer of ``nbytes`` (rounded up to 16). ``chunked``: kernels bind it a range at
        a time (:mod:`.chunks`), so it may exceed one binding, up to the buffer-size limit."""
        usage = usage if usage is not None else (
            wgpu.BufferUsage.STORAGE | wgpu.BufferUsage.COPY_SRC | wgpu.BufferUsage.COPY_DST)
        # zero-sized buffers are invalid; whole vec4s so any buffer can be read 16 bytes at a time
        nbytes = max(16, (int(nbytes) + 15) // 16 * 16)
        self.check_size(label or "buffer", nbytes, chunked)
        buf = self._tally(self.device.create_buffer(size=nbytes, usage=usage, label=label))
        if self.poison and usage & wgpu.BufferUsage.COPY_DST:
            self.queue.write_buffer(buf, 0, b"\xff" * nbytes)
        return buf

    def upload(self, array, label="", usage=None, chunked=False):
        """A new buffer holding ``array``'s bytes (``chunked``: as in :meth:`buffer`)."""
        arr = np.ascontiguousarray(array)
        if arr.nbytes == 0:
            arr = np.zeros(4, np.uint32)
        self.check_size(label or "buffer", arr.nbytes, chunked)
        usage = usage if usage is not None else (
            wgpu.BufferUsage.STORAGE | wgpu.BufferUsage.COPY_SRC | wgpu.BufferUsage.COPY_DST)
        if arr.nbytes % 16:   # whole vec4s (see buffer())
            arr = np.concatenate([arr.view(np.uint8).ravel(), np.zeros(16 - arr.nbytes % 16, np.uint8)])
        return self._tally(self.device.create_buffer_with_data(data=arr, usage=usage, label=label))

    def uniform(self, struct_value, label=""):
        """A uniform buffer holding ``struct_value``'s bytes. It must never be written: buffers
        of equal content are shared (:class:`~.bindings.UniformCache`; not in the tally)."""
        data = struct_value.tobytes()
        if not self.host_caching:
            return self._tally(self._make_uniform(data, label))
        return self._uniforms.get(data, label)

    def _make_uniform(self, data, label):
        return self.device.create_buffer_with_data(data=data, usage=wgpu.BufferUsage.UNIFORM, label=label)

    def binding_counts(self):
        """``(bind groups made, uniform buffers made)`` through the caches so far (benchmarks)."""
        return self._bind_groups.made, self._uniforms.made

    def bind_group(self, layout, entries):
        """The bind group of ``layout`` binding ``entries`` ``[(binding, buffer, offset, size)]``,
        made once while those buffers live (:class:`~.bindings.BindGroupCache`)."""
        if self.host_caching:
            return self._bind_groups.get(layout, entries)
        return self.device.create_bind_group(layout=layout, entries=[
            {"binding": slot, "resource": {"buffer": buf, "offset": int(off), "size": int(size)}}
            for slot, buf, off, size in entries])

    # A tally of device memory: every buffer made by buffer() or upload() (and uniform() with
    # the host caching off) counts from its creation until Python drops it (wgpu releases it
    # then). The cached uniform buffers (at most 1024 of a few hundred bytes) and buffers made on
    # ``self.device`` directly (the viewer's and MeshRenderer's, timestamp queries) are not
    # counted. A weakref finalizer per buffer: a few microseconds each. docs/memory.md.
    def _tally(self, buf):
        n, counts = int(buf.size), self._bytes
        counts[0] += n
        counts[1] = max(counts[1], counts[0])
        weakref.finalize(buf, _untally, counts, n).atexit = False
        return buf

    def live_bytes(self):
        """Bytes of this context's buffers (buffer, upload) still alive now."""
        return self._bytes[0]

    def peak_bytes(self):
        """The most :meth:`live_bytes` has been since :meth:`reset_peak` (or creation)."""
        return self._bytes[1]

    def reset_peak(self):
        """Start a new high-water mark for :meth:`peak_bytes` at the bytes alive now."""
        self._bytes[1] = self._bytes[0]

    def read(self, buffer, dtype, count=None, offset=0):
        dtype = np.dtype(dtype)
        size = None if count is None else int(count) * dtype.itemsize
        if size == 0:
            return np.zeros(0, dtype)
        data = self.queue.read_buffer(buffer, offset, size)
        out = np.frombuffer(data, dtype=dtype)
        # wgpu-py hands back a writable view of a fresh bytearray: the array can keep it
        # (a copy cost 1.4 s of reading a million SH-3 vertices' state back)
        return out if out.flags.writeable else out.copy()

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


def _untally(counts, n):
    counts[0] -= n


# -------------------------------------------------------------------- WGSL loading


# -------------------------------------------------------------------- dispatch
