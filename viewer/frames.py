"""What the viewer draws: the sources (a file's model, or a live trainer's device buffers) and
:class:`FrameRenderer`, which records one frame of a source into any colour target.

A frame: :meth:`MeshRenderer.draw` of the vertex / index buffers into an ``rgba32float``
target (rgb = colour, a = camera z, 0 = nothing; the same pipeline :meth:`MeshRenderer.render`
uses), or a line list pulled from the same storage buffers (wireframe,
``shaders/mesh/viewer_wire.wgsl``, coloured per vertex from the camera by the forward's own
``sh_to_color``), or :meth:`Renderer.forward` (the soft splatting render)
written into that target; then a present pass (``shaders/mesh/viewer_present.wgsl``) puts it
on the canvas's texture (background where nothing was drawn) with the HUD's text mask over the
top-left corner. Resources are bound by their WGSL names and the uniforms packed with the
struct dtypes reflected from the WGSL. Built only on the public API of ``tsplus_wgpu``.
"""

from __future__ import annotations

import numpy as np
import wgpu

from tsplus_wgpu import Camera, DeviceModel, MeshRenderer, Renderer, TriangleModel, clip_from_camera, load_wgsl

from .font import render_text

FLOAT_FORMAT = wgpu.TextureFormat.rgba32float
DEPTH_FORMAT = wgpu.TextureFormat.depth32float
WIRE_SHADER = "viewer_wire"
PRESENT_SHADER = "viewer_present"


# ---------------------------------------------------------------------------- sources
class ModelSource:
    """A :class:`TriangleModel` uploaded once: positions f32 [N, 3], SH f32 [N, K, 3]
    (the mesh draws its DC row), triangles u32 [M, 3]. ``colors`` [N, 3]: the mesh file's own
    vertex colours (fitted to the photos by ``tsplus train``), drawn in mesh mode instead of SH DC."""

    def __init__(self, renderer: Renderer, model: TriangleModel, sigma=None, stats=None, colors=None):
        dev = renderer.ctx.device
        self.renderer = renderer
        self.model = model
        usage = wgpu.BufferUsage.VERTEX | wgpu.BufferUsage.STORAGE | wgpu.BufferUsage.INDEX

        def up(a):
            b = np.ascontiguousarray(a).tobytes()
            return dev.create_buffer_with_data(data=b + bytes(-len(b) % 16 or (16 if not b else 0)), usage=usage)

        self.buffers = dict(positions=up(model.positions.astype(np.float32)),
                            sh=up(model.sh.astype(np.float32)),
                            triangles=up(model.triangles.astype(np.uint32)))
        self.num_vertices, self.num_triangles, self.sh_size = model.num_vertices, model.num_triangles, model.sh_size
        self.mesh_sh_size = self.sh_size
        if colors is not None and len(colors) == model.num_vertices:
            # plain RGB rows (the mesh pipeline's 12-byte colour attribute, sh_size None)
            self.buffers["mesh_colors"], self.mesh_sh_size = up(np.clip(colors, 0.0, 1.0).astype(np.float32)), None
        self.sigma = sigma
        self.stats = dict(stats or {})
        self._device_model = None

    @property
    def has_splat(self):
        """Whether the model carries splatting data (opacity below 1 or SH beyond DC)."""
        return self.model.sh_size > 1 or bool(np.any(self.model.opacity < 1.0))

    def splat_model(self):
        if self._device_model is None:
            self._device_model = DeviceModel.from_model(self.renderer, self.model)
        return self._device_model

    def refresh(self):
        pass


class TrainerSource:
    """A live trainer's device buffers, read every frame (topology edits replace them)."""

    has_splat = True

    def __init__(self, trainer):
        self.trainer = trainer
        self.renderer = trainer.renderer
        self.refresh()

    def refresh(self):
        t = self.trainer
        b = t.model.buffers
        self.buffers = dict(positions=b["positions"], sh=b["sh"], triangles=b["triangles"])
        self.num_vertices, self.num_triangles, self.sh_size = t.model.num_vertices, t.model.num_triangles, \
            t.model.sh_size
        self.sigma = t.sched.sigma(max(t.iteration, 1))
        s = t.last_stats or {}
        self.stats = dict(iteration=t.iteration, loss=s.get("loss"), psnr=s.get("psnr"))

    def splat_model(self):
        return self.trainer.model


# ---------------------------------------------------------------------------- frames
class FrameRenderer:
    """Records one frame of a source into a texture view of any colour format."""

    def __init__(self, renderer: Renderer, mesh_renderer: MeshRenderer | None = None, background=(0, 0, 0)):
        self.renderer = renderer
        self.ctx = renderer.ctx
        self.mesh = mesh_renderer or MeshRenderer(renderer.ctx)
        self.background = tuple(float(x) for x in background)
        dev = self.ctx.device
        self._wire_src, self._present_src = load_wgsl(WIRE_SHADER), load_wgsl(PRESENT_SHADER)
        self._wire_module = dev.create_shader_module(code=self._wire_src.code, label="viewer_wire")
        self._present_module = dev.create_shader_module(code=self._present_src.code, label="viewer_present")
        self._wire = dev.create_render_pipeline(
            layout="auto", label="viewer_wire",
            vertex={"module": self._wire_module, "entry_point": "vs_main", "buffers": []},
            primitive={"topology": wgpu.PrimitiveTopology.line_list},
            fragment={"module": self._wire_module, "entry_point": "fs_main", "targets": [{"format": FLOAT_FORMAT}]})
        self._present = {}
        self._targets = None
        self._hud = None      # (texture, w, h, key)
        self._wire_colors = None   # f32 [N, 4]: the wireframe's vertex colours, grown as N grows
        self._hud_size = (0, 0)

    def _present_pipeline(self, fmt):
        if fmt not in self._present:
            dev = self.ctx.device
            self._present[fmt] = dev.create_render_pipeline(
                layout="auto", label="viewer_present",
                vertex={"module": self._present_module, "entry_point": "vs_main", "buffers": []},
                primitive={"topology": wgpu.PrimitiveTopology.triangle_list},
                fragment={"module": self._present_module, "entry_point": "fs_main", "targets": [{"format": fmt}]})
        return self._present[fmt]

    def _frame_targets(self, w, h):
        if self._targets is None or self._targets[0] != (w, h):
            dev = self.ctx.device
            color = dev.create_texture(size=(w, h, 1), format=FLOAT_FORMAT,
                                       usage=wgpu.TextureUsage.RENDER_ATTACHMENT | wgpu.TextureUsage.TEXTURE_BINDING
                                       | wgpu.TextureUsage.COPY_DST)
            depth = dev.create_texture(size=(w, h, 1), format=DEPTH_FORMAT, usage=wgpu.TextureUsage.RENDER_ATTACHMENT)
            self._targets = ((w, h), color, color.create_view(), depth.create_view())
        return self._targets[1:]

    def set_hud(self, lines, scale=2):
        """Text lines for the HUD (None or [] hides it)."""
        if not lines:
            self._hud_size = (0, 0)
            return
        mask = render_text(lines, scale)
        h, w = mask.shape
        dev = self.ctx.device
        if self._hud is None or self._hud[1] < w or self._hud[2] < h:
            tw, th = max(w, 256), max(h, 64)
            tex = dev.create_texture(size=(tw, th, 1), format=wgpu.TextureFormat.r8unorm,
                                     usage=wgpu.TextureUsage.TEXTURE_BINDING | wgpu.TextureUsage.COPY_DST)
            self._hud = (tex, tw, th)
        self.ctx.queue.write_texture({"texture": self._hud[0], "mip_level": 0, "origin": (0, 0, 0)},
                                     np.ascontiguousarray(mask), {"offset": 0, "bytes_per_row": w, "rows_per_image": h},
                                     (w, h, 1))
        self._hud_size = (w, h)

    def _bind(self, pipeline, src, **resources):
        """A bind group of ``pipeline`` with each resource bound at its WGSL binding's slot, by name."""
        return self.ctx.device.create_bind_group(layout=pipeline.get_bind_group_layout(0), entries=[
            {"binding": src.bindings[name].slot, "resource": res} for name, res in resources.items()])

    def _record_wire(self, encoder, color_view, camera, source, near):
        """The wireframe: a line list pulled from the source's storage buffers."""
        b = source.buffers
        params = np.zeros((), self._wire_src.structs["WireParams"])
        params["clip_from_world"] = (clip_from_camera(camera, near) @ camera.world_to_camera).T.ravel()
        ubuf = self.ctx.device.create_buffer_with_data(data=params.tobytes(), usage=wgpu.BufferUsage.UNIFORM)
        # each vertex's colour from this camera, written by the forward's own kernel in ranges of
        # vertices, so SH larger than one storage binding colour every vertex
        n = max(int(source.num_vertices), 1)
        if self._wire_colors is None or self._wire_colors.size < 16 * n:
            self._wire_colors = self.ctx.device.create_buffer(size=16 * n, usage=wgpu.BufferUsage.STORAGE)
        self.renderer.record_vertex_colors(encoder, camera, b["positions"], b["sh"], self._wire_colors,
                                           source.num_vertices, source.sh_size)
        bind = self._bind(self._wire, self._wire_src, params={"buffer": ubuf}, positions={"buffer": b["positions"]},
                          triangles={"buffer": b["triangles"]}, colors={"buffer": self._wire_colors})
        rp = encoder.begin_render_pass(color_attachments=[{
            "view": color_view, "clear_value": (0.0, 0.0, 0.0, 0.0), "load_op": wgpu.LoadOp.clear,
            "store_op": wgpu.StoreOp.store}])
        if source.num_triangles:
            rp.set_pipeline(self._wire)
            rp.set_bind_group(0, bind)
            rp.draw(6 * source.num_triangles)
        rp.end()

    def record(self, encoder, target_view, target_format, camera: Camera, source, mode="mesh", near=0.01):
        """Record the frame of ``source`` seen by ``camera`` into ``target_view``.
        ``mode``: ``"mesh"`` (opaque, depth-tested), ``"wire"`` or ``"splat"``."""
        dev = self.ctx.device
        color, color_view, depth_view = self._frame_targets(camera.width, camera.height)
        b = source.buffers
        if mode == "splat" and source.has_splat:
            img = self.renderer.forward(source.splat_model(), camera, source.sigma, self.background, near).image
            rgba = np.concatenate([img, np.ones(img.shape[:2] + (1,), np.float32)], axis=2)
            self.ctx.queue.write_texture({"texture": color, "mip_level": 0, "origin": (0, 0, 0)},
                                         np.ascontiguousarray(rgba, np.float32),
                                         {"offset": 0, "bytes_per_row": 16 * camera.width,
                                          "rows_per_image": camera.height}, (camera.width, camera.height, 1))
        elif mode == "wire":
            self._record_wire(encoder, color_view, camera, source, near)
        else:
            self.mesh.draw(encoder, color_view, depth_view, camera, b["positions"], b.get("mesh_colors", b["sh"]),
                           b["triangles"], source.num_triangles,
                           sh_size=getattr(source, "mesh_sh_size", source.sh_size), near=near)
        if self._hud is None:
            self.set_hud(["."])
            self._hud_size = (0, 0)
        pp = np.zeros((), self._present_src.structs["PresentParams"])
        pp["background"][:3] = self.background
        pp["hud_size"] = self._hud_size
        ubuf = dev.create_buffer_with_data(data=pp.tobytes(), usage=wgpu.BufferUsage.UNIFORM)
        pipe = self._present_pipeline(target_format)
        bind = self._bind(pipe, self._present_src, params={"buffer": ubuf}, frame=color_view,
                          hud=self._hud[0].create_view())
        rp = encoder.begin_render_pass(color_attachments=[{
            "view": target_view, "clear_value": (0.0, 0.0, 0.0, 1.0), "load_op": wgpu.LoadOp.clear,
            "store_op": wgpu.StoreOp.store}])
        rp.set_pipeline(pipe)
        rp.set_bind_group(0, bind)
        rp.draw(3)
        rp.end()
