"""Depth-tested mesh rendering with a standard wgpu render pipeline: :class:`MeshRenderer`.

This is how an engine draws the exported mesh (vertex + fragment stages of
``shaders/mesh/mesh_raster.wgsl``, depth test, no blending, no face culling, vertex
colours), so novel-view metrics measured with it are the metrics of the plain mesh, not of
the splatting renderer. ``s x s`` supersampling renders at ``s`` times the resolution
(intrinsics scaled, so sample centres fall at ``(j + (k + 0.5)/s)``) and averages each
``s x s`` block on readback (area downsampling).

Its float64 NumPy twin is :func:`tsplus_wgpu.reference.mesh.mesh_raster`: a z-buffer on pixel centres.
"""

from __future__ import annotations

import numpy as np
import wgpu

from ..gpu.context import GpuContext
from ..gpu.wgsl import load_wgsl
from ..sh import mesh_arrays
from ..types import Camera

SHADER = "mesh/mesh_raster"
COLOR_FORMAT = wgpu.TextureFormat.rgba32float
DEPTH_FORMAT = wgpu.TextureFormat.depth32float
ROW_ALIGN = 256  # bytes_per_row of a texture-to-buffer copy must be a multiple of this

#: host side of ``struct MeshParams``, reflected from the WGSL
PARAMS_DTYPE = load_wgsl(SHADER).structs["MeshParams"]


def clip_from_camera(camera: Camera, near: float) -> np.ndarray:
    """The 4x4 projection P (float64) with clip = P x_cam: see the header of mesh_raster.wgsl."""
    w, h = camera.width, camera.height
    return np.array([[2 * camera.fx / w, 0.0, 2 * camera.cx / w - 1.0, 0.0],
                     [0.0, -2 * camera.fy / h, 1.0 - 2 * camera.cy / h, 0.0],
                     [0.0, 0.0, 0.0, near],
                     [0.0, 0.0, 1.0, 0.0]])


def mesh_params(camera: Camera, near: float, drop_near=True, linear_color=False, color_sh_dc=False):
    """The ``MeshParams`` uniform (one record of :data:`PARAMS_DTYPE`) for ``camera``."""
    params = np.zeros((), PARAMS_DTYPE)
    params["clip_from_world"] = (clip_from_camera(camera, near) @ camera.world_to_camera).T.ravel()  # column-major
    params["view_z"] = camera.world_to_camera[2]
    params["near"] = near
    params["drop_near"] = 1 if drop_near else 0
    params["linear_color"] = 1 if linear_color else 0
    params["color_sh_dc"] = 1 if color_sh_dc else 0
    return params


class MeshRenderResult:
    """``image`` [H, W, 3] float32 (area-downsampled), ``depth`` [H, W] camera z of the
    nearest surface at full supersampled resolution's block mean where covered (0 where
    nothing), ``coverage`` [H, W] share of the s x s samples covered."""

    def __init__(self, image, depth, coverage):
        self.image = image
        self.depth = depth
        self.coverage = coverage


class UploadedMesh:
    """A mesh whose vertex, colour and index buffers are on the device already
    (:meth:`MeshRenderer.upload`)."""

    def __init__(self, renderer, vbuf, cbuf, ibuf, count):
        self.renderer = renderer
        self.buffers = (vbuf, cbuf, ibuf, count)


class MeshRenderer:
    """Draws vertex-coloured triangle meshes with a depth-tested wgpu render pipeline.

    Args:
        adapter: None, an adapter name (``"lavapipe"``), a wgpu adapter, or a ``GpuContext``
            (share the one of a :class:`~tsplus_wgpu.Renderer` via ``renderer.ctx``).
    """

    def __init__(self, adapter=None):
        self.ctx = adapter if isinstance(adapter, GpuContext) else GpuContext(adapter)
        dev = self.ctx.device
        src = load_wgsl(SHADER)
        if src.bindings["params"].kind != "uniform":
            raise RuntimeError(f"{SHADER}.wgsl: expected the uniform 'params'")
        self.params_slot = src.bindings["params"].slot
        self.module = dev.create_shader_module(code=src.code, label="mesh_raster")
        self.bgl = dev.create_bind_group_layout(entries=[{
            "binding": self.params_slot, "visibility": wgpu.ShaderStage.VERTEX | wgpu.ShaderStage.FRAGMENT,
            "buffer": {"type": wgpu.BufferBindingType.uniform}}])
        self._layout = dev.create_pipeline_layout(bind_group_layouts=[self.bgl])
        self._pipelines = {}
        self.pipeline = self._pipeline(12)
        self._targets = {}
        self._geometry = None   # (key, vertex buffer, colour buffer, index buffer, count)

    def _pipeline(self, color_stride):
        """The render pipeline whose colour attribute is read every ``color_stride`` bytes
        (12: one RGB per vertex; 12 K: the DC row of a renderer-layout SH buffer [N, K, 3])."""
        if color_stride not in self._pipelines:
            self._pipelines[color_stride] = self._create_pipeline(color_stride)
        return self._pipelines[color_stride]

    def _create_pipeline(self, color_stride):
        dev = self.ctx.device
        vb = lambda loc, stride: {"array_stride": stride, "step_mode": wgpu.VertexStepMode.vertex,  # noqa: E731
                                  "attributes": [{"format": wgpu.VertexFormat.float32x3, "offset": 0,
                                                  "shader_location": loc}]}
        return dev.create_render_pipeline(
            layout=self._layout, label="mesh_raster",
            vertex={"module": self.module, "entry_point": "vs_main", "buffers": [vb(0, 12), vb(1, color_stride)]},
            primitive={"topology": wgpu.PrimitiveTopology.triangle_list, "cull_mode": wgpu.CullMode.none,
                       "front_face": wgpu.FrontFace.ccw},
            depth_stencil={"format": DEPTH_FORMAT, "depth_write_enabled": True,
                           "depth_compare": wgpu.CompareFunction.greater},
            multisample={"count": 1},
            fragment={"module": self.module, "entry_point": "fs_main",
                      "targets": [{"format": COLOR_FORMAT}]})

    @property
    def adapter_name(self):
        return self.ctx.name

    def _target(self, w, h):
        key = (w, h)
        if key not in self._targets:
            dev = self.ctx.device
            color = dev.create_texture(size=(w, h, 1), format=COLOR_FORMAT, usage=wgpu.TextureUsage.RENDER_ATTACHMENT
                                       | wgpu.TextureUsage.COPY_SRC)
            depth = dev.create_texture(size=(w, h, 1), format=DEPTH_FORMAT,
                                       usage=wgpu.TextureUsage.RENDER_ATTACHMENT)
            row = (w * 16 + ROW_ALIGN - 1) // ROW_ALIGN * ROW_ALIGN
            readback = dev.create_buffer(size=row * h, usage=wgpu.BufferUsage.COPY_DST | wgpu.BufferUsage.MAP_READ)
            self._targets = {key: (color, depth, row, readback)}   # keep one size alive
        return self._targets[key]

    def _buffers(self, pos, tri, col):
        """Vertex, colour and index buffers of checked arrays, and the index count."""
        dev = self.ctx.device
        usage_v = wgpu.BufferUsage.VERTEX | wgpu.BufferUsage.COPY_DST
        vbuf = dev.create_buffer_with_data(data=np.ascontiguousarray(pos, np.float32).tobytes() or bytes(12),
                                           usage=usage_v)
        cbuf = dev.create_buffer_with_data(data=np.ascontiguousarray(col, np.float32).tobytes() or bytes(12),
                                           usage=usage_v)
        idx = np.ascontiguousarray(tri, np.uint32).ravel()
        ibuf = dev.create_buffer_with_data(data=(idx.tobytes() if idx.size else bytes(12)),
                                           usage=wgpu.BufferUsage.INDEX | wgpu.BufferUsage.COPY_DST)
        return vbuf, cbuf, ibuf, int(idx.size)

    def _upload(self, pos, tri, col):
        key = (pos.ctypes.data, pos.shape, tri.ctypes.data, tri.shape, hash(col.tobytes()),
               hash(pos.tobytes()), hash(tri.tobytes()))
        if self._geometry is None or self._geometry[0] != key:
            self._geometry = (key, *self._buffers(pos, tri, col))
        return self._geometry[1:]

    def upload(self, mesh):
        """``mesh`` (as :meth:`render` takes it; a :class:`TriangleModel` gets its SH DC colour)
        checked and copied to the device once: :meth:`render` draws the returned
        :class:`UploadedMesh` from any camera without converting, checking or uploading it again
        (the colour fit draws one mesh from every training view)."""
        return UploadedMesh(self, *self._buffers(*mesh_arrays(mesh)))

    def draw(self, encoder, color_view, depth_view, camera: Camera, positions, colors, triangles, num_triangles,
             sh_size=None, near=0.01, drop_near=True):
        """Record a draw of caller-owned device buffers into caller-owned targets (no upload,
        no readback): how the live viewer draws the trainer's own buffers.

        Args:
            encoder: a wgpu command encoder (the render pass is recorded into it).
            color_view, depth_view: views of an ``rgba32float`` and a ``depth32float`` texture of
                the camera's size; both are cleared (rgb = colour, a = camera z, 0 where nothing).
            camera: the :class:`Camera`.
            positions: buffer of f32 ``[N, 3]`` (usage VERTEX).
            colors: buffer of f32 ``[N, 3]`` colours, or with ``sh_size = K`` the renderer's SH
                layout f32 ``[N, K, 3]`` whose DC row gives ``max(0, C0 dc + 0.5)`` (usage VERTEX).
            triangles: buffer of u32 ``[M, 3]`` (usage INDEX); ``num_triangles``: M.
        """
        params = mesh_params(camera, near, drop_near, color_sh_dc=bool(sh_size))
        self._record(encoder, color_view, depth_view, params, self._pipeline(12 * int(sh_size) if sh_size else 12),
                     positions, colors, triangles, 3 * int(num_triangles))

    def _record(self, encoder, color_view, depth_view, params, pipeline, vbuf, cbuf, ibuf, count):
        """One render pass: clear both targets, draw ``count`` indices with ``params``."""
        dev = self.ctx.device
        ubuf = dev.create_buffer_with_data(data=params.tobytes(), usage=wgpu.BufferUsage.UNIFORM)
        bind = dev.create_bind_group(layout=self.bgl, entries=[
            {"binding": self.params_slot, "resource": {"buffer": ubuf, "offset": 0, "size": PARAMS_DTYPE.itemsize}}])
        rp = encoder.begin_render_pass(
            color_attachments=[{"view": color_view, "clear_value": (0.0, 0.0, 0.0, 0.0),
                                "load_op": wgpu.LoadOp.clear, "store_op": wgpu.StoreOp.store}],
            depth_stencil_attachment={"view": depth_view, "depth_clear_value": 0.0,
                                      "depth_load_op": wgpu.LoadOp.clear, "depth_store_op": wgpu.StoreOp.store})
        if count:
            rp.set_pipeline(pipeline)
            rp.set_bind_group(0, bind)
            rp.set_vertex_buffer(0, vbuf)
            rp.set_vertex_buffer(1, cbuf)
            rp.set_index_buffer(ibuf, wgpu.IndexFormat.uint32)
            rp.draw_indexed(count)
        rp.end()

    def render(self, mesh, camera: Camera, supersample=1, background=(0.0, 0.0, 0.0), near=0.01,
               drop_near=True, interpolation="perspective"):
        """Draw ``mesh`` from ``camera``.

        Args:
            mesh: a :class:`TriangleModel` (colour from its SH for this camera; opacity
                ignored: the mesh is opaque), ``(positions [N,3], triangles [M,3], colors [N,3])``
                or an :class:`UploadedMesh` of this renderer (:meth:`upload`).
            camera: the :class:`Camera` (its exact pinhole model, pixel centres at +0.5).
            supersample: s >= 1; render at s x the resolution and average s x s blocks.
            background: RGB where nothing is drawn.
            near: near plane (camera z, scene units).
            drop_near: True (default, as the splatting renderer): a triangle with any vertex at
                z <= near is not drawn; False: clipped at the near plane as engines do.
            interpolation: ``"perspective"`` (default, as engines) or ``"linear"`` (affine in
                screen space, as the splatting model interpolates colour; only with drop_near).
        Returns:
            :class:`MeshRenderResult`.
        """
        if not isinstance(camera, Camera):
            raise ValueError(f"camera: expected tsplus_wgpu.Camera, got {type(camera).__name__}")
        s = int(supersample)
        if s != supersample or s < 1:
            raise ValueError(f"supersample: expected an integer >= 1, got {supersample!r}")
        if interpolation not in ("perspective", "linear"):
            raise ValueError(f"interpolation: expected 'perspective' or 'linear', got {interpolation!r}")
        if interpolation == "linear" and not drop_near:
            raise ValueError("interpolation='linear' (the splatting model's) needs drop_near=True, as that model")
        if not (np.isfinite(near) and near > 0):
            raise ValueError(f"near: expected a positive number, got {near!r}")
        bg = np.broadcast_to(np.asarray(background, np.float64), (3,))
        if isinstance(mesh, UploadedMesh):
            if mesh.renderer is not self:
                raise ValueError("mesh: uploaded by another MeshRenderer; upload it with this one")
            geometry = mesh.buffers
        else:
            geometry = self._upload(*mesh_arrays(mesh, camera))
        w, h = camera.width * s, camera.height * s
        lim = self.ctx.limits.get("max-texture-dimension-2d", 8192)
        if max(w, h) > lim:
            raise ValueError(f"supersample: {w}x{h} exceeds this device's texture limit of {lim} px; use a smaller s")
        cam = Camera(w, h, camera.fx * s, camera.fy * s, camera.cx * s, camera.cy * s, camera.world_to_camera)
        params = mesh_params(cam, near, drop_near, linear_color=interpolation == "linear")
        dev = self.ctx.device
        color, depth, row, readback = self._target(w, h)
        vbuf, cbuf, ibuf, count = geometry
        enc = dev.create_command_encoder()
        self._record(enc, color.create_view(), depth.create_view(), params, self.pipeline, vbuf, cbuf, ibuf, count)
        enc.copy_texture_to_buffer({"texture": color, "mip_level": 0, "origin": (0, 0, 0)},
                                   {"buffer": readback, "offset": 0, "bytes_per_row": row, "rows_per_image": h},
                                   (w, h, 1))
        self.ctx.queue.submit([enc.finish()])
        readback.map_sync(wgpu.MapMode.READ)
        try:
            raw = np.frombuffer(readback.read_mapped(), np.float32).copy()
        finally:
            readback.unmap()
        full = raw.reshape(h, row // 4)[:, :w * 4].reshape(h, w, 4)
        covered = full[..., 3] > 0
        rgb = np.where(covered[..., None], full[..., :3], bg.astype(np.float32))
        cov = covered.astype(np.float32)
        if s > 1:
            rgb = rgb.reshape(camera.height, s, camera.width, s, 3).mean(axis=(1, 3), dtype=np.float64)
            zsum = full[..., 3].reshape(camera.height, s, camera.width, s).sum(axis=(1, 3), dtype=np.float64)
            cov = cov.reshape(camera.height, s, camera.width, s).mean(axis=(1, 3))
            z = np.where(cov > 0, zsum / np.maximum(cov * s * s, 1), 0.0)
        else:
            z = full[..., 3]
        return MeshRenderResult(rgb.astype(np.float32), np.asarray(z, np.float32), np.asarray(cov, np.float32))


# --------------------------------------------------------------------------- NumPy twin
