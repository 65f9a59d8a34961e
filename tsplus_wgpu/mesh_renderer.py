"""Depth-tested mesh rendering with a standard wgpu render pipeline: :class:`MeshRenderer`.

This is how an engine draws the exported mesh (vertex + fragment stages of
``shaders/render/mesh_raster.wgsl``, depth test, no blending, no face culling, vertex
colours), so novel-view metrics measured with it are the metrics of the plain mesh, not of
the splatting renderer. ``s x s`` supersampling renders at ``s`` times the resolution
(intrinsics scaled, so sample centres fall at ``(j + (k + 0.5)/s)``) and averages each
``s x s`` block on readback (area downsampling).

:func:`render_reference` is its float64 NumPy twin: a z-buffer evaluated on pixel centres.
"""

from __future__ import annotations

import numpy as np
import wgpu

from .gpu import GpuContext, load_wgsl
from .types import Camera, TriangleModel

SHADER = "render/mesh_raster"
COLOR_FORMAT = wgpu.TextureFormat.rgba32float
DEPTH_FORMAT = wgpu.TextureFormat.depth32float
ROW_ALIGN = 256  # bytes_per_row of a texture-to-buffer copy must be a multiple of this

#: host side of ``struct MeshParams`` (mat4x4 is not in the reflected types; checked in tests)
PARAMS_DTYPE = np.dtype({"names": ["clip_from_world", "view_z", "near", "drop_near", "linear_color", "color_sh_dc"],
                         "formats": [("<f4", (16,)), ("<f4", (4,)), "<f4", "<u4", "<u4", "<u4"],
                         "offsets": [0, 64, 80, 84, 88, 92], "itemsize": 96})


def clip_from_camera(camera: Camera, near: float) -> np.ndarray:
    """The 4x4 projection P (float64) with clip = P x_cam: see the header of mesh_raster.wgsl."""
    w, h = camera.width, camera.height
    return np.array([[2 * camera.fx / w, 0.0, 2 * camera.cx / w - 1.0, 0.0],
                     [0.0, -2 * camera.fy / h, 1.0 - 2 * camera.cy / h, 0.0],
                     [0.0, 0.0, 0.0, near],
                     [0.0, 0.0, 1.0, 0.0]])


def _mesh_arrays(mesh, camera=None):
    """(positions [N,3], triangles [M,3], colors [N,3]) from a TriangleModel (colour
    max(0, SH(dir) + 0.5) for ``camera``, as the splatting model), or a (positions,
    triangles, colors) triple."""
    if isinstance(mesh, TriangleModel):
        from .reference import vertex_colors
        if mesh.sh_size == 1 or camera is None:
            from .reference import SH_C0
            col = np.maximum(mesh.sh[:, 0] * SH_C0 + 0.5, 0.0)
        else:
            col = vertex_colors(mesh.positions, mesh.sh, camera.center)
        return mesh.positions, mesh.triangles, col
    try:
        pos, tri, col = mesh
    except Exception:
        raise ValueError("mesh: expected a TriangleModel or a (positions, triangles, colors) triple") from None
    pos = np.asarray(pos, np.float64)
    tri = np.asarray(tri)
    col = np.asarray(col, np.float64)
    if pos.ndim != 2 or pos.shape[1] != 3:
        raise ValueError(f"positions: expected shape [N, 3], got {pos.shape}")
    if tri.ndim != 2 or tri.shape[1] != 3:
        raise ValueError(f"triangles: expected shape [M, 3], got {tri.shape}")
    if col.shape != pos.shape:
        raise ValueError(f"colors: expected shape {pos.shape}, got {col.shape}")
    if tri.size and (tri.min() < 0 or tri.max() >= len(pos)):
        raise ValueError(f"triangles: index out of range [0, {len(pos)})")
    if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(col))):
        raise ValueError("mesh: non-finite positions or colours")
    return pos, tri.astype(np.int64), col


class MeshRenderResult:
    """``image`` [H, W, 3] float32 (area-downsampled), ``depth`` [H, W] camera z of the
    nearest surface at full supersampled resolution's block mean where covered (0 where
    nothing), ``coverage`` [H, W] share of the s x s samples covered."""

    def __init__(self, image, depth, coverage):
        self.image = image
        self.depth = depth
        self.coverage = coverage


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
        if src.bindings["params"].kind != "uniform" or src.bindings["params"].slot != 0:
            raise RuntimeError(f"{SHADER}.wgsl: expected the uniform 'params' at binding 0")
        self.module = dev.create_shader_module(code=src.code, label="mesh_raster")
        self.bgl = dev.create_bind_group_layout(entries=[{
            "binding": 0, "visibility": wgpu.ShaderStage.VERTEX | wgpu.ShaderStage.FRAGMENT,
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

    def _upload(self, pos, tri, col):
        key = (pos.ctypes.data, pos.shape, tri.ctypes.data, tri.shape, hash(col.tobytes()),
               hash(pos.tobytes()), hash(tri.tobytes()))
        if self._geometry is None or self._geometry[0] != key:
            dev = self.ctx.device
            usage_v = wgpu.BufferUsage.VERTEX | wgpu.BufferUsage.COPY_DST
            vbuf = dev.create_buffer_with_data(data=np.ascontiguousarray(pos, np.float32).tobytes() or bytes(12),
                                               usage=usage_v)
            cbuf = dev.create_buffer_with_data(data=np.ascontiguousarray(col, np.float32).tobytes() or bytes(12),
                                               usage=usage_v)
            idx = np.ascontiguousarray(tri, np.uint32).ravel()
            ibuf = dev.create_buffer_with_data(data=(idx.tobytes() if idx.size else bytes(12)),
                                               usage=wgpu.BufferUsage.INDEX | wgpu.BufferUsage.COPY_DST)
            self._geometry = (key, vbuf, cbuf, ibuf, int(idx.size))
        return self._geometry[1:]

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
        params = np.zeros((), PARAMS_DTYPE)
        params["clip_from_world"] = (clip_from_camera(camera, near) @ camera.world_to_camera).T.ravel()
        params["view_z"] = camera.world_to_camera[2]
        params["near"] = near
        params["drop_near"] = 1 if drop_near else 0
        params["color_sh_dc"] = 1 if sh_size else 0
        dev = self.ctx.device
        ubuf = dev.create_buffer_with_data(data=params.tobytes(), usage=wgpu.BufferUsage.UNIFORM)
        bind = dev.create_bind_group(layout=self.bgl, entries=[
            {"binding": 0, "resource": {"buffer": ubuf, "offset": 0, "size": PARAMS_DTYPE.itemsize}}])
        rp = encoder.begin_render_pass(
            color_attachments=[{"view": color_view, "clear_value": (0.0, 0.0, 0.0, 0.0),
                                "load_op": wgpu.LoadOp.clear, "store_op": wgpu.StoreOp.store}],
            depth_stencil_attachment={"view": depth_view, "depth_clear_value": 0.0,
                                      "depth_load_op": wgpu.LoadOp.clear, "depth_store_op": wgpu.StoreOp.store})
        if num_triangles:
            rp.set_pipeline(self._pipeline(12 * int(sh_size) if sh_size else 12))
            rp.set_bind_group(0, bind)
            rp.set_vertex_buffer(0, positions)
            rp.set_vertex_buffer(1, colors)
            rp.set_index_buffer(triangles, wgpu.IndexFormat.uint32)
            rp.draw_indexed(3 * int(num_triangles))
        rp.end()

    def render(self, mesh, camera: Camera, supersample=1, background=(0.0, 0.0, 0.0), near=0.01,
               drop_near=True, interpolation="perspective"):
        """Draw ``mesh`` from ``camera``.

        Args:
            mesh: a :class:`TriangleModel` (colour from its SH for this camera; opacity
                ignored: the mesh is opaque) or ``(positions [N,3], triangles [M,3], colors [N,3])``.
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
        pos, tri, col = _mesh_arrays(mesh, camera)
        w, h = camera.width * s, camera.height * s
        lim = self.ctx.limits.get("max-texture-dimension-2d", 8192)
        if max(w, h) > lim:
            raise ValueError(f"supersample: {w}x{h} exceeds this device's texture limit of {lim} px; use a smaller s")
        cam = Camera(w, h, camera.fx * s, camera.fy * s, camera.cx * s, camera.cy * s, camera.world_to_camera)
        params = np.zeros((), PARAMS_DTYPE)
        m = clip_from_camera(cam, near) @ cam.world_to_camera
        params["clip_from_world"] = m.T.ravel()   # WGSL matrices are column-major
        params["view_z"] = cam.world_to_camera[2]
        params["near"] = near
        params["drop_near"] = 1 if drop_near else 0
        params["linear_color"] = 1 if interpolation == "linear" else 0
        dev = self.ctx.device
        ubuf = dev.create_buffer_with_data(data=params.tobytes(), usage=wgpu.BufferUsage.UNIFORM)
        bind = dev.create_bind_group(layout=self.bgl, entries=[
            {"binding": 0, "resource": {"buffer": ubuf, "offset": 0, "size": PARAMS_DTYPE.itemsize}}])
        color, depth, row, readback = self._target(w, h)
        vbuf, cbuf, ibuf, count = self._upload(pos, tri, col)
        enc = dev.create_command_encoder()
        rp = enc.begin_render_pass(
            color_attachments=[{"view": color.create_view(), "clear_value": (0.0, 0.0, 0.0, 0.0),
                                "load_op": wgpu.LoadOp.clear, "store_op": wgpu.StoreOp.store}],
            depth_stencil_attachment={"view": depth.create_view(), "depth_clear_value": 0.0,
                                      "depth_load_op": wgpu.LoadOp.clear, "depth_store_op": wgpu.StoreOp.store})
        if count:
            rp.set_pipeline(self.pipeline)
            rp.set_bind_group(0, bind)
            rp.set_vertex_buffer(0, vbuf)
            rp.set_vertex_buffer(1, cbuf)
            rp.set_index_buffer(ibuf, wgpu.IndexFormat.uint32)
            rp.draw_indexed(count)
        rp.end()
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

def render_reference(mesh, camera: Camera, background=(0.0, 0.0, 0.0), near=0.01, drop_near=True,
                     interpolation="perspective", edge_tol=1e-4, subpixel_bits=None):
    """Float64 z-buffer twin of :meth:`MeshRenderer.render` at s = 1, evaluated on pixel
    centres. Returns ``(image [H,W,3], depth [H,W] (0 = nothing), triangle id [H,W] (-1),
    ambiguous [H,W] bool)``: ambiguous where a pixel centre is within ``edge_tol`` px of an
    edge of a triangle that covers it or nearly does (the hardware's tie rule decides there),
    or where two surfaces are within 1e-5 relative depth. Triangles crossing the near plane
    are dropped (``drop_near``) or rejected with ValueError otherwise (not modelled).

    ``subpixel_bits``: rasterisers snap projected vertices to a fixed-point grid of
    ``2**-bits`` px before the coverage test (Vulkan guarantees >= 4 bits; lavapipe and the
    desktop GPUs use 8), which moves edges by up to ~``0.7 * 2**-bits`` px; give the bits to
    snap the same way for the coverage test (None: exact positions); depth and colour
    are interpolated from the exact positions, as the hardware does to within float32."""
    pos, tri, col = _mesh_arrays(mesh, camera)
    h, w = camera.height, camera.width
    cam_pts = pos @ camera.R.T + camera.t
    z = cam_pts[:, 2]
    img = np.empty((h, w, 3))
    img[:] = np.asarray(background, np.float64)
    inv_depth = np.zeros((h, w))
    second = np.zeros((h, w))
    tid = np.full((h, w), -1, np.int64)
    amb = np.zeros((h, w), bool)
    zs = np.where(z > 0, z, 1.0)
    uv = np.stack([camera.fx * cam_pts[:, 0] / zs + camera.cx, camera.fy * cam_pts[:, 1] / zs + camera.cy], 1)
    uv_cover = uv if subpixel_bits is None else np.round(uv * 2.0 ** subpixel_bits) / 2.0 ** subpixel_bits
    for t, (a, b, c) in enumerate(tri):
        if min(z[a], z[b], z[c]) <= near:
            if drop_near:
                continue
            raise ValueError("render_reference: near-plane clipping is not modelled; use drop_near=True")
        pa, pb, pc = uv[a], uv[b], uv[c]
        area = (pb[0] - pa[0]) * (pc[1] - pa[1]) - (pb[1] - pa[1]) * (pc[0] - pa[0])
        if area == 0:
            continue
        lo = np.floor(np.minimum(np.minimum(pa, pb), pc) - 1).astype(int)
        hi = np.ceil(np.maximum(np.maximum(pa, pb), pc) + 1).astype(int)
        x0, y0 = max(lo[0], 0), max(lo[1], 0)
        x1, y1 = min(hi[0], w), min(hi[1], h)
        if x0 >= x1 or y0 >= y1:
            continue
        py, px = np.mgrid[y0:y1, x0:x1] + 0.5

        def edge(p, q):  # signed distance (px) of the centres from line p->q, positive inside for area > 0
            e = (q[0] - p[0]) * (py - p[1]) - (q[1] - p[1]) * (px - p[0])
            return e / np.hypot(q[0] - p[0], q[1] - p[1]) * np.sign(area)

        qa, qb, qc = uv_cover[a], uv_cover[b], uv_cover[c]
        ea, eb, ec = edge(qb, qc), edge(qc, qa), edge(qa, qb)
        dmin = np.minimum(np.minimum(ea, eb), ec)
        inside = dmin > 0
        near_edge = np.abs(dmin) <= edge_tol
        # screen barycentrics
        la = ((pb[0] - px) * (pc[1] - py) - (pb[1] - py) * (pc[0] - px)) / area
        lb = ((pc[0] - px) * (pa[1] - py) - (pc[1] - py) * (pa[0] - px)) / area
        lc = 1.0 - la - lb
        iz = la / z[a] + lb / z[b] + lc / z[c]            # 1/z is affine in screen space
        if interpolation == "linear":
            cc = la[..., None] * col[a] + lb[..., None] * col[b] + lc[..., None] * col[c]
        else:
            cc = (la[..., None] * col[a] / z[a] + lb[..., None] * col[b] / z[b] + lc[..., None] * col[c] / z[c]) \
                / iz[..., None]
        sub_amb = amb[y0:y1, x0:x1]
        sub_amb |= near_edge & (iz >= inv_depth[y0:y1, x0:x1] * (1 - 1e-3))
        win = inside & (iz > inv_depth[y0:y1, x0:x1])
        loser = inside & ~win
        sec = second[y0:y1, x0:x1]
        sec[win] = inv_depth[y0:y1, x0:x1][win]
        sec[loser] = np.maximum(sec[loser], iz[loser])
        inv_depth[y0:y1, x0:x1][win] = iz[win]
        img[y0:y1, x0:x1][win] = cc[win]
        tid[y0:y1, x0:x1][win] = t
    amb |= (second > 0) & (np.abs(inv_depth - second) <= 1e-5 * inv_depth)
    depth = np.where(inv_depth > 0, 1.0 / np.where(inv_depth > 0, inv_depth, 1.0), 0.0)
    return img, depth, tid, amb
