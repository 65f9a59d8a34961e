"""The forward rasterizer on the device: SH -> colour, projection, depth sort, tile
binning, sort by tile, tile ranges, blend. Results stay on the device; reading
``image``, ``transmittance`` or ``max_weight`` copies them back on first access."""

from __future__ import annotations

import functools

import numpy as np

from ..gpu.context import GpuContext
from ..gpu.recorder import Recorder
from ..kernels.bin import BinCount, BinEmit, BinItems, BinRows, TileRanges
from ..kernels.reduce import MaxReduce
from ..kernels.sort import PrefixSum, RadixSort
from ..kernels.project import ProjectTriangles, ShToColor, frame_params
from ..kernels.blend import GatherTris, forward_stage
from ..gpu.chunks import binding_bytes, pair_windows
from ..gpu.stage import Scratch
from ..gpu.wgsl import constant
from .device_model import DeviceModel
from ..types import Camera, TriangleModel, check_render_args

#: the forward's and backward's buffers bound a range of triangles at a time (``gpu/chunks.py``)
CHUNKED = ("tris", "tri_stats", "corner_grads")

TILE = constant("TILE")                            # pixels per tile side (frame.wgsl)
MAX_TILES_PER_ROW = constant("MAX_TILES_PER_ROW")  # binning's loop over a row of tiles (frame.wgsl)


class ForwardResult:
    """Output of :meth:`Renderer.forward`. Device buffers are kept for the backward pass;
    the numpy views below are read back lazily, once each."""

    def __init__(self, renderer, camera, model, sigma, background, near, buffers, num_pairs, timings,
                 model_buffers=None, max_tile_pairs=0, reused=False):
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
        #: the buffers are the renderer's scratch (``forward(reuse=True)``), and so are the
        #: backward's: the next such forward or backward overwrites them
        self.reused = reused

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
        return np.ascontiguousarray(self._read("triangle_ids", np.int32, 2 * h * w).reshape(h, w, 2)[..., 0])

    @property
    def triangle_id_weights(self):  # [H, W] float32
        """The blending weight alpha * T of ``triangle_ids`` at each pixel (0 where none)."""
        if "triangle_ids" not in self.buffers:
            raise ValueError("triangle_id_weights: not computed; call Renderer.forward(..., triangle_ids=True)")
        h, w = self.camera.height, self.camera.width
        state = self._read("triangle_ids", np.uint32, 2 * h * w).reshape(h, w, 2)   # (id, weight bits)
        return np.ascontiguousarray(state[..., 1]).view(np.float32)

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
        return self._read("ranges", np.uint32, 2 * self.renderer.tiles(self.camera)[2]).reshape(-1, 2)


def _read_u32(ctx, buf):
    return int(ctx.read(buf, np.uint32, 1)[0])


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
        self.blend = forward_stage(c)     # in the context's kernel layout
        self.gather = GatherTris(c)
        self._ids = None           # RasterizeIds, compiled on first use (forward(triangle_ids=True))
        self.tri2d_dtype = self.project.src.structs["Tri2D"]   # projected triangle records

    @property
    def adapter_name(self):
        return self.ctx.name

    @staticmethod
    def tiles(camera):
        """(tiles_x, tiles_y, tiles) of the image of ``camera``."""
        tx = (camera.width + TILE - 1) // TILE
        ty = (camera.height + TILE - 1) // TILE
        return tx, ty, tx * ty

    _tiles = tiles   # the names render/backward.py uses

    def frame_params(self, model, camera, sigma, background, near, num_pairs, num_rows=0):
        """The ``FrameParams`` uniform of one view (counts known so far: ``num_pairs``, ``num_rows``)."""
        return frame_params(self.project, camera, sigma, background, near, num_vertices=model.num_vertices,
                            num_triangles=model.num_triangles, sh_k=model.sh_size, num_pairs=num_pairs,
                            num_rows=num_rows)

    _frame_params = frame_params

    def record_vertex_colors(self, encoder, camera, positions, sh, colors, num_vertices, sh_size):
        """Record into ``encoder`` each vertex's colour seen from ``camera``, ``(max(0, SH(dir) +
        0.5), 1)`` (the forward's own ``sh_to_color``), from caller-owned buffers: ``positions`` f32
        ``[N, 3]``, ``sh`` f32 ``[N, K, 3]`` (any size up to the device's buffer limit: bound a range
        of vertices at a time), ``colors`` f32 ``[N, 4]`` (written). No upload, no readback: how the
        live viewer colours its wireframe from the trainer's own buffers."""
        n = int(num_vertices)
        if n:
            params = frame_params(self.sh_to_color, camera, 1.0, num_vertices=n, sh_k=int(sh_size))
            self.sh_to_color(encoder, params, positions, sh, colors, n, None, int(sh_size))

    def upload_model(self, model: TriangleModel):
        """Device buffers of a model (float32 / uint32)."""
        c = self.ctx
        return dict(
            positions=c.upload(model.positions.astype(np.float32), "positions"),
            triangles=c.upload(model.triangles.astype(np.uint32), "triangles"),
            sh=c.upload(model.sh.astype(np.float32), "sh", chunked=True),   # a range of vertices a binding
            opacity=c.upload(model.opacity.astype(np.float32), "opacity"),
        )

    def forward(self, model, camera, sigma, background=(0.0, 0.0, 0.0), near=0.01, profile=False,
                triangle_ids=False, reuse=False):
        """Render ``model`` seen by ``camera``.

        Args:
            model: :class:`TriangleModel` with at least one triangle, or a
                :class:`~tsplus_wgpu.DeviceModel` already on this renderer's device (no upload).
            camera: :class:`Camera`.
            sigma: window sharpness (> 0); 1 is soft, 1e-4 is nearly a hard triangle.
            background: RGB added where light passes through (weight T).
            near: triangles with a vertex at camera z <= near are not drawn.
            profile: time each stage (timestamp queries where supported, else host timing).
            triangle_ids: also run the ID pass (``rasterize_forward.wgsl`` with ``TRIANGLE_IDS``)
                over the same sorted tile lists; off by default, so the normal forward pays nothing for it.
            reuse: take the result's buffers from this renderer's scratch (no new buffers, and
                the kernels' bind groups are made once): the next forward with ``reuse``
                overwrites them, so the result must not be used after it (the training step).

        Returns:
            :class:`ForwardResult` with ``image [H, W, 3]``, ``transmittance [H, W]``,
            ``max_weight [M]`` and, with ``triangle_ids``, ``triangle_ids [H, W]`` int32
            (read back on first access).
        """
        camera, sigma, bg, near = self._check_forward(model, camera, sigma, background, near)
        # Timing: timestamp queries per pass where supported; otherwise each stage is
        # submitted on its own and timed on the host.
        rec = Recorder(self.ctx, profile)
        alloc = self.buffer_source(reuse, "forward_")
        dev = model.buffers if isinstance(model, DeviceModel) else self.upload_model(model)
        frame = functools.partial(self.frame_params, model, camera, sigma, bg, near)
        b, rows_total = self._project(rec, frame(0, 0), dev, model, camera, alloc)
        num_rows = _read_u32(self.ctx, rows_total)         # sizes the (triangle, tile row) items
        b, num_pairs, max_tile_pairs = self._count_pairs(rec, frame(0, num_rows), b, model, camera, num_rows, alloc)
        params = frame(num_pairs, num_rows)
        self._sort_and_blend(rec, params, b, model, camera, num_rows, num_pairs, max_tile_pairs, triangle_ids, alloc)
        if triangle_ids:
            self._triangle_id_pass(rec, params, b, camera, max_tile_pairs, model.num_triangles, num_pairs)
        times = rec.resolve()
        return ForwardResult(self, camera, model, sigma, tuple(bg), near, b, num_pairs, times, model_buffers=dev,
                             max_tile_pairs=max_tile_pairs, reused=bool(reuse))

    def buffer_source(self, reuse, prefix):
        """``(bytes, name) -> buffer``: a new buffer, or with ``reuse`` this renderer's scratch
        buffer ``prefix + name`` (kept between calls, so the kernels' bind groups are too)."""
        # the per-triangle records may outgrow one binding: bound a page at a time (gpu/chunks.py)
        if reuse:   # exact sizes: they follow the largest view, with no slack on top
            return lambda nbytes, name: self.scratch.get(prefix + name, nbytes, grow=1.0, chunked=name in CHUNKED)
        return lambda nbytes, name: self.ctx.buffer(nbytes, name, chunked=name in CHUNKED)

    def _check_forward(self, model, camera, sigma, background, near):
        """The checked ``(camera, sigma, background, near)`` of :meth:`forward`; raises
        ValueError for a model, camera or image size this device cannot render."""
        if isinstance(model, DeviceModel):
            if model.ctx is not self.ctx:
                raise ValueError("model: its buffers belong to another device (GpuContext)")
        elif not isinstance(model, TriangleModel):
            raise ValueError(f"model: expected tsplus_wgpu.TriangleModel or DeviceModel, got {type(model).__name__}")
        camera = _as_camera(camera)
        sigma, bg, near = check_render_args(sigma, background, near)
        m, n = model.num_triangles, model.num_vertices
        if m == 0:
            raise ValueError("model: it has no triangles (M = 0); nothing to render")
        c = self.ctx
        h, w = camera.height, camera.width
        tx, ty, _ = self.tiles(camera)
        for name, nbytes in (("image", 12 * h * w), ("triangles", 12 * m)):
            c.check_size(name, nbytes)
        # bound a range of vertices / triangles at a time (gpu/chunks.py)
        c.check_size("sh", 12 * n * model.sh_size, chunked=True)
        c.check_size("projected triangles", self.tri2d_dtype.itemsize * m, chunked=True)
        # binning loops over one row of tiles per invocation (lavapipe's loop budget)
        if tx > MAX_TILES_PER_ROW or ty > c.limits["max-compute-workgroups-per-dimension"]:
            raise ValueError(f"camera: {w}x{h} is too large; width up to {TILE * MAX_TILES_PER_ROW} px and height up "
                             f"to {TILE * c.limits['max-compute-workgroups-per-dimension']} px are supported")
        return camera, sigma, bg, near

    def _project(self, rec, params, dev, model, camera, alloc):
        """Stage 1: colours, projection, depth order, tile rows per triangle. Returns the buffers
        and the one holding the number of (triangle, tile row) items (submitted, to be read)."""
        prof, flush = rec.profiler, rec.flush
        m, n = model.num_triangles, model.num_vertices
        b = dict(
            colors=alloc(16 * n, "colors"),
            tris=alloc(self.tri2d_dtype.itemsize * m, "tris"),
            pixel_rects=alloc(16 * m, "pixel_rects"),
            depth_keys=alloc(4 * m, "depth_keys"),
            tri_ids=alloc(4 * m, "tri_ids"),
            row_offsets=alloc(4 * m, "row_offsets"),
            tile_counts=alloc(4 * self.tiles(camera)[2], "tile_counts"),
            max_tile_pairs=alloc(16, "max_tile_pairs"),
        )
        rec.start()
        self.sh_to_color(rec.encoder, params, dev["positions"], dev["sh"], b["colors"], n, prof, model.sh_size)
        flush("sh_to_color")
        self.project(rec.encoder, params, dev["positions"], dev["triangles"], dev["opacity"], b["colors"],
                     b["tris"], b["pixel_rects"], b["depth_keys"], b["tri_ids"], m, prof)
        flush("project_triangles")
        keys, order = self.depth_sort.record(rec.encoder, b["depth_keys"], b["tri_ids"], m, 32, prof)
        assert order is b["tri_ids"]   # 8 passes: the result lands back in the input buffers
        b["tri_from_rank"] = order
        flush("depth_sort")
        self.bin_rows(rec.encoder, params, b["pixel_rects"], order, b["row_offsets"], m, prof)
        rows_total = self.scan.record(rec.encoder, b["row_offsets"], m, profiler=prof, label="bin_rows")
        flush("bin_rows", force=True)
        return b, rows_total

    def _count_pairs(self, rec, params, b, model, camera, num_rows, alloc):
        """Stage 2: count the pairs of every item, and per tile. Returns the buffers, the
        number of pairs (sizes the pair buffers) and the longest tile list (blend passes)."""
        c, prof, flush = self.ctx, rec.profiler, rec.flush
        m, ntiles, order = model.num_triangles, self.tiles(camera)[2], b["tri_from_rank"]
        b["counts"] = alloc(4 * num_rows, "counts")
        b["item_rank"] = alloc(4 * num_rows, "item_rank")
        self.bin_items(rec.encoder, params, b["pixel_rects"], order, b["row_offsets"], b["item_rank"], m, prof)
        flush("bin_rows")
        self.bin_count(rec.encoder, params, b["tris"], b["pixel_rects"], order, b["row_offsets"], b["item_rank"],
                       b["counts"], b["tile_counts"], num_rows, prof, num_triangles=m)
        pairs_total = self.scan.record(rec.encoder, b["counts"], num_rows, profiler=prof, label="bin_count")
        self.max_reduce(rec.encoder, b["tile_counts"], b["max_tile_pairs"], ntiles, prof, "bin_count")
        # both counts in one readback (one wait for the device, not two): the total beside the maximum
        rec.encoder.copy_buffer_to_buffer(pairs_total, 0, b["max_tile_pairs"], 4, 4)
        flush("bin_count", force=True)
        max_tile_pairs, num_pairs = (int(v) for v in c.read(b["max_tile_pairs"], np.uint32, 2))
        c.check_size("tile-triangle pairs (image size x triangles)", 4 * num_pairs)
        return b, num_pairs, max_tile_pairs

    def _sort_and_blend(self, rec, params, b, model, camera, num_rows, num_pairs, max_tile_pairs, triangle_ids,
                        alloc):
        """Stage 3: write the pairs, sort them by tile (stable: depth order within a tile),
        tile ranges, blend. Adds the pair and output buffers to ``b``."""
        prof, flush = rec.profiler, rec.flush
        m, order = model.num_triangles, b["tri_from_rank"]
        h, w = camera.height, camera.width
        tx, ty, ntiles = self.tiles(camera)
        b["pair_tiles"] = alloc(4 * num_pairs, "pair_tiles")
        b["pair_tris"] = alloc(4 * num_pairs, "pair_tris")
        b["ranges"] = alloc(8 * ntiles, "ranges")
        b["image"] = alloc(12 * h * w, "image")
        b["final_t"] = alloc(4 * h * w, "final_t")
        b["n_contrib"] = alloc(8 * h * w, "n_contrib")
        b["max_weight"] = alloc(4 * m, "max_weight")
        b["work"] = alloc(16, "work")
        self.bin_emit(rec.encoder, params, b["tris"], b["pixel_rects"], order, b["row_offsets"], b["item_rank"],
                      b["counts"], b["pair_tiles"], b["pair_tris"], num_rows, prof, num_triangles=m)
        flush("bin_emit")
        tile_bits = max(1, int(ntiles - 1).bit_length())
        keys, vals = self.tile_sort.record(rec.encoder, b["pair_tiles"], b["pair_tris"], num_pairs, tile_bits, prof)
        if keys is not b["pair_tiles"]:
            rec.encoder.copy_buffer_to_buffer(keys, 0, b["pair_tiles"], 0, 4 * max(num_pairs, 1))
            rec.encoder.copy_buffer_to_buffer(vals, 0, b["pair_tris"], 0, 4 * max(num_pairs, 1))
        flush("tile_sort")
        self.tile_ranges(rec.encoder, b["pair_tiles"], b["ranges"], num_pairs, prof)
        flush("tile_ranges")
        for i, (tris, window) in enumerate(self._tri_windows(rec, b, m, num_pairs, max_tile_pairs, alloc)):
            self.blend(rec.encoder, params, b["ranges"], b["pair_tris"], tris, b["image"], b["final_t"],
                       b["n_contrib"], b["max_weight"], b["work"], tx, ty, max_tile_pairs, prof, window, clear=i == 0)
        flush("rasterize_forward", force=not triangle_ids)

    def tri_windows(self, num_triangles, num_pairs, max_tile_pairs):
        """None where a view's projected triangles fit one storage binding; else the windows of
        its pairs ``[(lo, hi, length)]`` whose records, gathered in pair order, fit one (the last
        window also takes the empty tiles that start after the last pair)."""
        size = self.tri2d_dtype.itemsize
        cap = binding_bytes(self.ctx)
        if num_triangles * size <= cap:
            return None
        wins = pair_windows(num_pairs, max_tile_pairs, cap // size, "projected triangles of one window of pairs")
        return wins[:-1] + [(wins[-1][0], 0xFFFFFFFF, wins[-1][2])]

    def _tri_windows(self, rec, b, m, num_pairs, max_tile_pairs, alloc=None):
        """Yields ``(tris binding, window)`` for the blend and ID passes: ``(b["tris"], None)``
        where they fit one binding, else per window of pairs its records gathered into one
        buffer (recorded before the window's blend)."""
        wins = self.tri_windows(m, num_pairs, max_tile_pairs)
        if wins is None:
            yield b["tris"], None
            return
        size = self.tri2d_dtype.itemsize
        out = (alloc or (lambda nbytes, name: self.ctx.buffer(nbytes, name)))(
            size * max(max(length for _, _, length in wins), 1), "tris_window")
        for lo, hi, length in wins:
            self.gather(rec.encoder, b["pair_tris"], b["tris"], out, lo, length, m, size, rec.profiler)
            yield out, (lo, hi)

    def _triangle_id_pass(self, rec, params, b, camera, max_tile_pairs, m, num_pairs):
        """The ID pass over the sorted pairs in ``b``: adds ``triangle_ids`` ``[H, W]`` (ID,
        weight bits) and ``id_t`` ``[H, W]`` (its T) to ``b``."""
        c = self.ctx
        h, w = camera.height, camera.width
        tx, ty, _ = self.tiles(camera)
        if self._ids is None:
            self._ids = forward_stage(c, triangle_ids=True)
        b["id_t"] = c.buffer(4 * h * w, "id_t")
        b["triangle_ids"] = c.buffer(8 * h * w, "triangle_ids")
        for tris, window in self._tri_windows(rec, b, m, num_pairs, max_tile_pairs):
            self._ids(rec.encoder, params, b["ranges"], b["pair_tris"], tris, b["id_t"], b["triangle_ids"],
                      tx, ty, max_tile_pairs, rec.profiler, window)
        rec.flush("rasterize_ids", force=True)

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
        (see :func:`tsplus_wgpu.render.backward.backward`): ``Grads`` with ``v_positions [N, 3]``,
        ``v_sh [N, K, 3]``, ``v_opacity [N]``. Portable and deterministic. ``v_image`` may be a
        device buffer ``[H * W]`` vec4 (dL/d rgb, dL/d T); with ``out`` (device buffers) and
        ``read=False`` the gradients stay on the device."""
        from .backward import backward
        return backward(self, result, v_image, v_transmittance, read=read, out=out)
