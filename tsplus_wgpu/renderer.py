"""The forward rasterizer on the device: SH -> colour, projection, depth sort, tile
binning, sort by tile, tile ranges, blend. Results stay on the device; reading
``image``, ``transmittance`` or ``max_weight`` copies them back on first access."""

from __future__ import annotations

import time

import numpy as np

from . import reference
from .gpu import GpuContext, Profiler
from .stages import (BinCount, BinEmit, BinItems, BinRows, MaxReduce, PrefixSum, ProjectTriangles, RadixSort,
                     RasterizeForward, RasterizeIds, Scratch, ShToColor, TileRanges)
from .device_model import DeviceModel
from .types import Camera, TriangleModel

TILE = 16
TRI2D_FLOATS = 24
MAX_TILES_PER_ROW = 16384


class ForwardResult:
    """Output of :meth:`Renderer.forward`. Device buffers are kept for the backward pass;
    the numpy views below are read back lazily, once each."""

    def __init__(self, renderer, camera, model, sigma, background, near, buffers, num_pairs, timings,
                 model_buffers=None, max_tile_pairs=0):
        self.renderer = renderer
        self.camera = camera
        self.model = model
        self.sigma = sigma
        self.background = background
        self.near = near
        self.buffers = buffers
        self.num_pairs = num_pairs
        self.timings = timings     # {stage: ms} when profiled, else {}
        self._cache = {}
        #: the model's device buffers the forward read (the backward reuses them, no re-upload)
        self.model_buffers = model_buffers
        #: the longest tile list (sizes the blend's passes, forward and backward)
        self.max_tile_pairs = max_tile_pairs

    def _read(self, name, dtype, count):
        key = (name, np.dtype(dtype).str)
        if key not in self._cache:
            self._cache[key] = self.renderer.ctx.read(self.buffers[name], dtype, count)
        return self._cache[key]

    @property
    def image(self):  # [H, W, 3] float32
        h, w = self.camera.height, self.camera.width
        return self._read("image", np.float32, h * w * 3).reshape(h, w, 3)

    @property
    def transmittance(self):  # [H, W] float32
        h, w = self.camera.height, self.camera.width
        return self._read("final_t", np.float32, h * w).reshape(h, w)

    @property
    def max_weight(self):  # [M] float32
        return self._read("max_weight", np.uint32, self.model.num_triangles).view(np.float32)

    @property
    def triangle_ids(self):  # [H, W] int32
        """Per pixel the index of the triangle with the largest blending weight alpha * T (ties:
        the front-most), -1 where no triangle contributes. Needs ``forward(..., triangle_ids=True)``."""
        if "triangle_ids" not in self.buffers:
            raise ValueError("triangle_ids: not computed; call Renderer.forward(..., triangle_ids=True)")
        h, w = self.camera.height, self.camera.width
        return self._read("triangle_ids", np.int32, h * w).reshape(h, w)

    @property
    def triangle_id_weights(self):  # [H, W] float32
        """The blending weight alpha * T of ``triangle_ids`` at each pixel (0 where none)."""
        if "id_state" not in self.buffers:
            raise ValueError("triangle_id_weights: not computed; call Renderer.forward(..., triangle_ids=True)")
        h, w = self.camera.height, self.camera.width
        return self._read("id_state", np.uint32, 4 * h * w).reshape(h, w, 4)[..., 1].view(np.float32)

    @property
    def n_contrib(self):  # [H, W] pairs up to the last contributing one
        h, w = self.camera.height, self.camera.width
        return self._read("n_contrib", np.uint32, 2 * h * w).reshape(h, w, 2)[..., 0]

    @property
    def n_evaluated(self):  # [H, W] pairs evaluated before stopping
        h, w = self.camera.height, self.camera.width
        return self._read("n_contrib", np.uint32, 2 * h * w).reshape(h, w, 2)[..., 1]

    @property
    def work(self):
        """Blend work for FLOP accounting: dict of pair evaluations, of those that reached
        the window's power (ratio >= tau), and of contributions."""
        w = self._read("work", np.uint32, 2)
        return {"evaluations": int(self.n_evaluated.astype(np.int64).sum()), "powered": int(w[0]),
                "contributions": int(w[1])}

    # Intermediate stages, for tests and tools.
    def projected(self):
        """Tri2D records as a structured array [M] and the pixel boxes [M, 4]."""
        m = self.model.num_triangles
        dt = self.renderer.tri2d_dtype
        raw = self.renderer.ctx.read(self.buffers["tris"], np.uint8, m * dt.itemsize)
        rects = self._read("pixel_rects", np.int32, 4 * m).reshape(m, 4)
        return raw.view(dt), rects

    def depth_order(self):  # [M] triangle index by rank
        return self._read("tri_from_rank", np.uint32, self.model.num_triangles)

    def pairs(self):
        """(tile, triangle) pairs after the sort: ordered by tile, then depth."""
        p = self.num_pairs
        return self._read("pair_tiles", np.uint32, p), self._read("pair_tris", np.uint32, p)

    def tile_ranges(self):
        return self._read("ranges", np.uint32, 2 * self.renderer._tiles(self.camera)[2]).reshape(-1, 2)


def _as_camera(camera):
    if not isinstance(camera, Camera):
        raise ValueError(f"camera: expected tsplus_wgpu.Camera, got {type(camera).__name__}")
    return camera


class Renderer:
    """Forward rasterizer on a wgpu device.

    Args:
        adapter: None (best adapter; ``TSPLUS_ADAPTER`` if set), a name such as
            ``"lavapipe"`` or ``"nvidia"``, a wgpu adapter, or an existing ``GpuContext``.
    """

    def __init__(self, adapter=None):
        self.ctx = adapter if isinstance(adapter, GpuContext) else GpuContext(adapter)
        c = self.ctx
        self.scratch = Scratch(c)
        self.sh_to_color = ShToColor(c)
        self.project = ProjectTriangles(c)
        self.bin_rows = BinRows(c)
        self.bin_items = BinItems(c)
        self.bin_count = BinCount(c)
        self.max_reduce = MaxReduce(c)
        self.bin_emit = BinEmit(c)
        self.scan = PrefixSum(c, self.scratch)
        self.depth_sort = RadixSort(c, self.scratch, "depth_sort")
        self.tile_sort = RadixSort(c, self.scratch, "tile_sort")
        self.tile_ranges = TileRanges(c)
        self.blend = RasterizeForward(c)
        self._ids = None           # RasterizeIds, compiled on first use (forward(triangle_ids=True))
        self.tri2d_dtype = self.project.src.structs["Tri2D"]
        assert self.tri2d_dtype.itemsize == 4 * TRI2D_FLOATS

    @property
    def adapter_name(self):
        return self.ctx.name

    @staticmethod
    def _tiles(camera):
        tx = (camera.width + TILE - 1) // TILE
        ty = (camera.height + TILE - 1) // TILE
        return tx, ty, tx * ty

    def _frame_params(self, model, camera, sigma, background, near, num_pairs, num_rows=0):
        tx, ty, _ = self._tiles(camera)
        R, t = camera.R, camera.t
        return self.project.uniform(
            "FrameParams",
            rot0=[*R[0], t[0]], rot1=[*R[1], t[1]], rot2=[*R[2], t[2]],
            cam_center=[*camera.center, 0.0], background=[*background, 0.0],
            fx=camera.fx, fy=camera.fy, cx=camera.cx, cy=camera.cy, near=near, sigma=sigma,
            width=camera.width, height=camera.height, tiles_x=tx, tiles_y=ty,
            num_vertices=model.num_vertices, num_triangles=model.num_triangles, sh_k=model.sh_size,
            num_pairs=num_pairs, num_rows=num_rows)

    def upload_model(self, model: TriangleModel):
        """Device buffers of a model (float32 / uint32)."""
        c = self.ctx
        return dict(
            positions=c.upload(model.positions.astype(np.float32), "positions"),
            triangles=c.upload(model.triangles.astype(np.uint32), "triangles"),
            sh=c.upload(model.sh.astype(np.float32), "sh"),
            opacity=c.upload(model.opacity.astype(np.float32), "opacity"),
        )

    def forward(self, model, camera, sigma, background=(0.0, 0.0, 0.0), near=0.01, profile=False,
                triangle_ids=False):
        """Render ``model`` seen by ``camera``.

        Args:
            model: :class:`TriangleModel` with at least one triangle, or a
                :class:`~tsplus_wgpu.DeviceModel` already on this renderer's device (no upload).
            camera: :class:`Camera`.
            sigma: window sharpness (> 0); 1 is soft, 1e-4 is nearly a hard triangle.
            background: RGB added where light passes through (weight T).
            near: triangles with a vertex at camera z <= near are not drawn.
            profile: time each stage (timestamp queries where supported, else host timing).
            triangle_ids: also run the ID pass (``shaders/rasterize_ids.wgsl``) over the same
                sorted tile lists; off by default, so the normal forward pays nothing for it.

        Returns:
            :class:`ForwardResult` with ``image [H, W, 3]``, ``transmittance [H, W]``,
            ``max_weight [M]`` and, with ``triangle_ids``, ``triangle_ids [H, W]`` int32
            (read back on first access).
        """
        if isinstance(model, DeviceModel):
            if model.ctx is not self.ctx:
                raise ValueError("model: its buffers belong to another device (GpuContext)")
        elif not isinstance(model, TriangleModel):
            raise ValueError(f"model: expected tsplus_wgpu.TriangleModel or DeviceModel, got {type(model).__name__}")
        camera = _as_camera(camera)
        sigma, bg, near = reference._check_args(sigma, background, near)
        m, n = model.num_triangles, model.num_vertices
        if m == 0:
            raise ValueError("model: it has no triangles (M = 0); nothing to render")
        c = self.ctx
        h, w = camera.height, camera.width
        tx, ty, ntiles = self._tiles(camera)
        for name, nbytes in (("image", 12 * h * w), ("triangles", 12 * m), ("sh", 12 * n * model.sh_size),
                             ("projected triangles", 4 * TRI2D_FLOATS * m)):
            c.check_size(name, nbytes)
        # binning loops over one row of tiles per invocation (lavapipe's loop budget)
        if tx > MAX_TILES_PER_ROW or ty > c.limits["max-compute-workgroups-per-dimension"]:
            raise ValueError(f"camera: {w}x{h} is too large; width up to {16 * MAX_TILES_PER_ROW} px and height up "
                             f"to {16 * c.limits['max-compute-workgroups-per-dimension']} px are supported")

        # Timing: timestamp queries per pass where supported; otherwise each stage is
        # submitted on its own and timed on the host.
        prof = Profiler(c) if profile and c.features.timestamps else None
        host_timing = profile and prof is None
        times = {}
        state = {"enc": c.device.create_command_encoder(), "t": time.perf_counter()}

        def flush(label, force=False):
            if not (host_timing or force):
                return
            c.queue.submit([state["enc"].finish()])
            state["enc"] = c.device.create_command_encoder()
            if host_timing:
                c.wait()
                now = time.perf_counter()
                times[label] = times.get(label, 0.0) + (now - state["t"]) * 1e3
                state["t"] = now

        def read_u32(buf):
            return int(c.read(buf, np.uint32, 1)[0])

        dev = model.buffers if isinstance(model, DeviceModel) else self.upload_model(model)
        params = self._frame_params(model, camera, sigma, bg, near, 0, 0)
        b = dict(
            colors=c.buffer(16 * n, "colors"),
            tris=c.buffer(4 * TRI2D_FLOATS * m, "tris"),
            pixel_rects=c.buffer(16 * m, "pixel_rects"),
            depth_keys=c.buffer(4 * m, "depth_keys"),
            tri_ids=c.buffer(4 * m, "tri_ids"),
            row_offsets=c.buffer(4 * m, "row_offsets"),
            tile_counts=c.buffer(4 * ntiles, "tile_counts"),
            max_tile_pairs=c.buffer(16, "max_tile_pairs"),
        )
        if host_timing:
            c.wait()
            state["t"] = time.perf_counter()

        # 1. colours, projection, depth order, tile rows per triangle
        self.sh_to_color(state["enc"], params, dev["positions"], dev["sh"], b["colors"], n, prof)
        flush("sh_to_color")
        self.project(state["enc"], params, dev["positions"], dev["triangles"], dev["opacity"], b["colors"],
                     b["tris"], b["pixel_rects"], b["depth_keys"], b["tri_ids"], m, prof)
        flush("project_triangles")
        keys, order = self.depth_sort.record(state["enc"], b["depth_keys"], b["tri_ids"], m, 32, prof)
        assert order is b["tri_ids"]   # 8 passes: the result lands back in the input buffers
        b["tri_from_rank"] = order
        flush("depth_sort")
        self.bin_rows(state["enc"], params, b["pixel_rects"], order, b["row_offsets"], m, prof)
        rows_total = self.scan.record(state["enc"], b["row_offsets"], m, profiler=prof, label="bin_rows")
        flush("bin_rows", force=True)
        num_rows = read_u32(rows_total)                # sizes the (triangle, tile row) items

        # 2. count the pairs of every item, and per tile
        params = self._frame_params(model, camera, sigma, bg, near, 0, num_rows)
        b["counts"] = c.buffer(4 * num_rows, "counts")
        b["item_rank"] = c.buffer(4 * num_rows, "item_rank")
        self.bin_items(state["enc"], params, b["pixel_rects"], order, b["row_offsets"], b["item_rank"], m, prof)
        flush("bin_rows")
        self.bin_count(state["enc"], params, b["tris"], b["pixel_rects"], order, b["row_offsets"], b["item_rank"],
                       b["counts"], b["tile_counts"], num_rows, prof)
        pairs_total = self.scan.record(state["enc"], b["counts"], num_rows, profiler=prof, label="bin_count")
        self.max_reduce(state["enc"], b["tile_counts"], b["max_tile_pairs"], ntiles, prof, "bin_count")
        flush("bin_count", force=True)
        num_pairs = read_u32(pairs_total)              # sizes the pair buffers
        max_tile_pairs = read_u32(b["max_tile_pairs"])  # blend passes
        c.check_size("tile-triangle pairs (image size x triangles)", 4 * num_pairs)

        # 3. write the pairs, sort them by tile (stable: depth order within a tile), blend
        params = self._frame_params(model, camera, sigma, bg, near, num_pairs, num_rows)
        b["pair_tiles"] = c.buffer(4 * num_pairs, "pair_tiles")
        b["pair_tris"] = c.buffer(4 * num_pairs, "pair_tris")
        b["ranges"] = c.buffer(8 * ntiles, "ranges")
        b["image"] = c.buffer(12 * h * w, "image")
        b["final_t"] = c.buffer(4 * h * w, "final_t")
        b["n_contrib"] = c.buffer(8 * h * w, "n_contrib")
        b["max_weight"] = c.buffer(4 * m, "max_weight")
        b["work"] = c.buffer(16, "work")
        self.bin_emit(state["enc"], params, b["tris"], b["pixel_rects"], order, b["row_offsets"], b["item_rank"],
                      b["counts"], b["pair_tiles"], b["pair_tris"], num_rows, prof)
        flush("bin_emit")
        tile_bits = max(1, int(ntiles - 1).bit_length())
        keys, vals = self.tile_sort.record(state["enc"], b["pair_tiles"], b["pair_tris"], num_pairs, tile_bits, prof)
        if keys is not b["pair_tiles"]:
            state["enc"].copy_buffer_to_buffer(keys, 0, b["pair_tiles"], 0, 4 * max(num_pairs, 1))
            state["enc"].copy_buffer_to_buffer(vals, 0, b["pair_tris"], 0, 4 * max(num_pairs, 1))
        flush("tile_sort")
        self.tile_ranges(state["enc"], b["pair_tiles"], b["ranges"], num_pairs, prof)
        flush("tile_ranges")
        self.blend(state["enc"], params, b["ranges"], b["pair_tris"], b["tris"], b["image"], b["final_t"],
                   b["n_contrib"], b["max_weight"], b["work"], tx, ty, max_tile_pairs, prof)
        flush("rasterize_forward", force=not triangle_ids)
        if triangle_ids:
            if self._ids is None:
                self._ids = RasterizeIds(c)
            b["id_state"] = c.buffer(16 * h * w, "id_state")
            b["triangle_ids"] = c.buffer(4 * h * w, "triangle_ids")
            self._ids(state["enc"], params, b["ranges"], b["pair_tris"], b["tris"], b["id_state"],
                      b["triangle_ids"], tx, ty, max_tile_pairs, prof)
            flush("rasterize_ids", force=True)
        if prof is not None:
            times = prof.resolve()
        return ForwardResult(self, camera, model, sigma, tuple(bg), near, b, num_pairs, times, model_buffers=dev,
                             max_tile_pairs=max_tile_pairs)

    def triangle_ids(self, model, camera, sigma=1e-4, near=0.01, opaque=True):
        """The triangle-ID buffer ``[H, W]`` int32 of ``model`` seen by ``camera``: per pixel the
        triangle with the largest blending weight alpha * T (ties: the front-most), -1 where none.

        Args:
            model: :class:`TriangleModel` (or a :class:`~tsplus_wgpu.DeviceModel` with ``opaque=False``).
            sigma: window sharpness; the default 1e-4 draws nearly hard triangles.
            opaque: draw every vertex at opacity 1 and with DC colour only, as the exported
                mesh is (colours do not change the IDs; opacity does).
        """
        if opaque and isinstance(model, TriangleModel):
            model = TriangleModel(model.positions, model.triangles, model.sh[:, :1], np.ones(model.num_vertices))
        return self.forward(model, camera, sigma, near=near, triangle_ids=True).triangle_ids

    def backward(self, result, v_image, v_transmittance=None, read=True, out=None):
        """Gradients of ``sum(v_image * image) + sum(v_transmittance * T)`` of ``result``
        (see :func:`tsplus_wgpu.backward.backward`): ``Grads`` with ``v_positions [N, 3]``,
        ``v_sh [N, K, 3]``, ``v_opacity [N]``. Portable and deterministic. ``v_image`` may be a
        device buffer ``[H * W]`` vec4 (dL/d rgb, dL/d T); with ``out`` (device buffers) and
        ``read=False`` the gradients stay on the device."""
        from .backward import backward
        return backward(self, result, v_image, v_transmittance, read=read, out=out)
