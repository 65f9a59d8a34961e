"""What training costs in device memory (docs/memory.md): :func:`training_bytes` and
:func:`largest_model`, read off the code rather than measured.

:func:`training_buffers` lists every buffer alive at the peak of one training step (during the
backward pass, when the forward's buffers are still held) with the size the code gives it:

* **per vertex** (``Trainer.set_state``): positions, SH (``[N, K, 3]``, which the renderer reads
  as they are) and opacity logits, each with Adam's two moments; the renderer's opacity; the
  renderer's gradients (``v_positions`` and ``v_sh`` are the parameters' too) and the logits'
  gradient; the opacity loss's per-vertex sums; the forward's colours and the backward's vertex
  sums and each vertex's run of the corners sorted by vertex (``corner_spans``, its per-vertex
  gather); the position step's scale by depth (``position_lr_depth``, on by default; 4 bytes a
  vertex more than a run without it).
* **per triangle**: the index buffer, the corners' order by vertex, the
  topology's running max weight; the forward's projected record ``Tri2D`` (size read from the
  WGSL), pixel boxes, depth keys and order, row offsets, max weights and the depth sort's
  scratch; the backward's per-triangle statistics and corner gradients (the corners' order by
  vertex is sorted once per topology and handed to the backward as the model's
  ``corner_order``: no sort per step; the segmented sum's scratch only where the corner gradients
  outgrow one binding, ``max_binding``, and the per-vertex gather gives way to it).
* **per pixel** (at the supersampled size ``s^2 W H`` unless marked): image, transmittance,
  per-pixel counts, the backward's state and its vec4 input; tile counts and ranges; at ``W H``:
  the loss's (``ImageLoss``: 112 bytes a pixel, and ``v_image``) and the downsampled image.
* **per tile-triangle pair**: keys and values, the tile sort's and the pair sort's scratch, the
  backward's per-pair statistics (``NSTAT`` floats) and their segmented sum (these last, with
  the pair sort, for at most one window of pairs at a time: ``pair_window``); and per
  (triangle, tile row) item, which the binning sizes by its own count (``rows``; at most one
  item per pair, so ``pairs`` bounds it); with ``max_binding``, where the projected triangles
  outgrow one binding, the forward's and the backward's gathered window of records.
* **targets**: the training images, uploaded once per view and kept (``views`` of them).

Not counted: uniform buffers (a few hundred bytes, one per dispatch), the normal loss (a second
forward and backward of an unshared model of ``3 M`` vertices; :mod:`.normals`), evaluation
renders, profiling queries and the viewer. Sizes follow :meth:`GpuContext.buffer` (16-byte
multiples, at least 16) and :class:`~tsplus_wgpu.gpu.Scratch` (256-byte multiples; a scratch buffer
that grows takes 1.5 times its old size when that is more, so after a larger view it may hold more
than this says).
"""

from __future__ import annotations

import functools

from ..gpu.wgsl import constant, load_wgsl

FAMILIES = ("vertex", "triangle", "pixel", "pair", "targets", "other")


@functools.lru_cache(maxsize=None)
def _consts():
    return dict(tri2d=int(load_wgsl("project_triangles").structs["Tri2D"].itemsize),
                nstat=int(constant("NSTAT", "grad_stats")), tile=int(constant("TILE")),
                sort_block=int(constant("SORT_BLOCK", "radix_count")), radix=int(constant("RADIX", "radix_count")),
                radix_bits=int(constant("RADIX_BITS", "radix_count")),
                scan_block=int(constant("SCAN_BLOCK", "scan_block")), chunk=int(constant("CHUNK", "segment_up")),
                ssim_group=int(load_wgsl("ssim_loss").invocations), ssim_seg=int(constant("SSIM_SEG", "ssim")))


def _ceil(a, b):
    return -(-int(a) // int(b))


def _buf(nbytes):        # GpuContext.buffer / upload
    return max(16, _ceil(nbytes, 16) * 16)


def _scratch(nbytes):    # Scratch.get (first allocation)
    return _ceil(max(16, int(nbytes)), 256) * 256


def _sort_scratch(name, n, bits, c):
    """RadixSort.record's scratch for ``n`` keys: ``[(name, bytes)]`` and the scanned lengths."""
    if n <= 1 or bits <= 0:
        return [], []
    nb = _ceil(n, c["sort_block"])
    return ([(f"{name}_counts", _scratch(4 * c["radix"] * nb)), (f"{name}_keys_alt", _scratch(4 * n)),
             (f"{name}_vals_alt", _scratch(4 * n))], [c["radix"] * nb])


def _segment_scratch(name, n, width, c):
    """SegmentSum.record's scratch for ``n`` elements of ``width`` vec4s (one pair per level)."""
    out, depth = [], 1
    while n > c["chunk"]:
        n = _ceil(n, c["chunk"])
        out += [(f"{name}_keys_{depth}", _scratch(4 * n)), (f"{name}_vals_{depth}", _scratch(16 * width * n))]
        depth += 1
    return out


def _scan_scratch(lengths, c):
    """``scan_sums_<level>``, shared by every PrefixSum on the renderer's scratch: the largest."""
    sizes = {}
    for n in lengths:
        level = 0
        while True:
            nb = max(1, _ceil(n, c["scan_block"]))          # Stage.groups: at least one
            sizes[level] = max(sizes.get(level, 0), _scratch(4 * nb))
            if nb == 1:
                break
            n, level = nb, level + 1
    return [(f"scan_sums_{level}", b) for level, b in sorted(sizes.items())]


def training_buffers(num_vertices, num_triangles, sh_degree, width, height, pairs, supersample=1, rows=None,
                     views=1, pair_window=None, max_binding=None):
    """Every buffer alive at the peak of one training step: ``[(family, name, bytes)]``.

    Args:
        num_vertices, num_triangles: N and M of the model.
        sh_degree: the SH degree of the model's storage (K = (degree + 1)^2 per channel).
        width, height: the training view's size (pixels).
        pairs: tile-triangle pairs of the view's forward (``ForwardResult.num_pairs``, at the
            supersampled size).
        supersample: s, the per-axis supersampling of the step (``Trainer.fit_supersample``).
        rows: (triangle, tile row) items of the forward (default ``pairs``, which bounds them).
        views: training images on the device (the trainer keeps each view's once it was used).
        pair_window: the most pairs the backward takes at once (its windows,
            :func:`~tsplus_wgpu.render.backward.pair_windows`: one storage binding of their
            statistics); None: all of them at once.
        max_binding: the device's storage-binding size (bytes); where the projected triangles
            outgrow it, the forward and the backward each read a window's records gathered into
            a buffer of their own (at most one binding). None: not counted.
    """
    c = _consts()
    n, m, k = int(num_vertices), int(num_triangles), (int(sh_degree) + 1) ** 2
    p, s = int(width) * int(height), max(1, int(supersample))
    sub = p * s * s                                              # pixels rendered
    tiles = _ceil(int(width) * s, c["tile"]) * _ceil(int(height) * s, c["tile"])
    P = int(pairs)
    R = P if rows is None else int(rows)
    Pw = P if pair_window is None else min(P, int(pair_window))      # the backward's window
    V, T, X, Q, O = "vertex", "triangle", "pixel", "pair", "other"
    out = [(V, name, _buf(b)) for name, b in (
        # Trainer.set_state: parameters and Adam moments (positions and SH double as the
        # render's; v_sh is the SH's gradient)
        ("positions", 12 * n), ("exp_avg_positions", 12 * n), ("exp_avg_sq_positions", 12 * n),
        ("sh", 12 * n * k), ("exp_avg_sh", 12 * n * k), ("exp_avg_sq_sh", 12 * n * k),
        ("logits", 4 * n), ("exp_avg_logits", 4 * n), ("exp_avg_sq_logits", 4 * n),
        ("render_opacity", 4 * n),
        ("v_positions", 12 * n), ("v_sh", 12 * n * k), ("v_opacity", 4 * n),
        ("v_logits", 4 * n), ("opacity_reg_vertex", 16 * n),
        ("colors", 16 * n), ("vertex_sums", 32 * n), ("corner_spans", 8 * n))]           # forward, backward
    out.append((V, "position_lr_scale", _scratch(4 * n)))          # the position step by depth (default on)
    out.append((V, "opacity_reg_counts", _scratch(4 * n)))         # the early opacity loss's counts
    out += [(T, name, _buf(b)) for name, b in (
        ("triangles", 12 * m), ("corner_order_keys", 12 * m), ("corner_order_index", 12 * m),
        ("max_weight_acc", 4 * m),
        ("tris", c["tri2d"] * m), ("pixel_rects", 16 * m), ("depth_keys", 4 * m), ("tri_ids", 4 * m),
        ("row_offsets", 4 * m), ("max_weight", 4 * m),                                  # forward
        ("tri_stats", 4 * c["nstat"] * m), ("corner_grads", 32 * 3 * m))]             # backward
    depth, scan_depth = _sort_scratch("depth_sort", m, 32, c)
    out += [(T, name, b) for name, b in depth]
    if max_binding is not None and 32 * 3 * m > int(max_binding):
        # the corner gradients past one binding: the segmented sum in pages, not the per-vertex gather
        # (which also gives way to it for a vertex of over SegmentGather.MAX_RUN corners: not counted)
        out += [(T, name, b) for name, b in _segment_scratch("corner_sum", 3 * m, 2, c)]
    out += [(X, name, _buf(b)) for name, b in (
        ("image", 12 * sub), ("final_t", 4 * sub), ("n_contrib", 8 * sub), ("tile_counts", 4 * tiles),
        ("ranges", 8 * tiles), ("backward_state", 16 * sub))]
    out += [(X, name, _scratch(b)) for name, b in (
        ("train_v_out", 16 * sub), ("train_v_image", 12 * p), ("ssim_rows", 64 * p), ("ssim_dmaps", 48 * p),
        ("ssim_partials", 8 * _ceil(width * _ceil(height, c["ssim_seg"]), c["ssim_group"])))]
    if s > 1:
        out.append((X, "train_image_down", _scratch(12 * p)))
    out += [(Q, name, _buf(b)) for name, b in (
        ("counts", 4 * R), ("item_rank", 4 * R), ("pair_tiles", 4 * P), ("pair_tris", 4 * P),   # forward
        ("pair_keys", 4 * Pw), ("pair_ids", 4 * Pw), ("partials", 4 * c["nstat"] * Pw))]      # backward
    out.append((Q, "pair_ids_fresh", _buf(4 * Pw)))      # 0, 1, ...: each window's ids start from a copy
    if max_binding is not None and c["tri2d"] * m > int(max_binding):
        # the projected triangles past one binding: a window's records, gathered in pair order
        window = min(P, int(max_binding) // c["tri2d"]) * c["tri2d"]
        out += [(Q, "forward_tris_window", _buf(window)), (Q, "backward_tris_window", _buf(window))]
    tile, scan_tile = _sort_scratch("tile_sort", P, max(1, (tiles - 1).bit_length()), c)
    pair, scan_pair = _sort_scratch("pair_sort", Pw, max(1, (m - 1).bit_length()), c)
    out += [(Q, name, b) for name, b in tile + pair + _segment_scratch("pair_sum", Pw, c["nstat"] // 4, c)]
    out += [(O, name, b) for name, b in _scan_scratch([m, R] + scan_depth + scan_tile + scan_pair, c)]
    out += [("targets", f"target_{i}", _buf(12 * p)) for i in range(int(views))]
    out += [(O, name, b) for name, b in (("max_tile_pairs", 16), ("work", 16), ("backward_work", 16),
                                         ("train_loss", 256), ("fence", 16))]
    return out


def training_bytes(num_vertices, num_triangles, sh_degree, width, height, pairs, supersample=1, rows=None,
                   views=1, pair_window=None, max_binding=None):
    """Device bytes of one training step at its peak, by buffer family (:data:`FAMILIES`) and
    ``total``. Arguments: :func:`training_buffers`."""
    out = dict.fromkeys(FAMILIES, 0)
    for family, _, nbytes in training_buffers(num_vertices, num_triangles, sh_degree, width, height, pairs,
                                              supersample, rows, views, pair_window, max_binding):
        out[family] += nbytes
    out["total"] = sum(out[f] for f in FAMILIES)
    return out


#: the buffers bound a range of vertices or triangles at a time, or read gathered per window of
#: pairs (``gpu/chunks.py``): each must fit one buffer, not one binding
CHUNKED = ("sh", "exp_avg_sh", "exp_avg_sq_sh", "v_sh", "tris", "tri_stats", "corner_grads")


def largest_model(memory_bytes, sh_degree, width, height, pairs_per_pixel, triangles_per_vertex, supersample=1,
                  views=1, max_binding=None, max_buffer=2**31 - 256):
    """The most vertices whose training fits ``memory_bytes`` of device memory, for a model with
    ``triangles_per_vertex`` triangles a vertex whose views give ``pairs_per_pixel`` tile-triangle
    pairs per rendered pixel (at ``supersample``; the arguments of :func:`training_buffers`).
    With ``max_binding`` (bytes) every single buffer must also fit one storage binding (WebGPU's
    default: 128 MiB), but those of :data:`CHUNKED` one buffer of ``max_buffer`` bytes, and the
    backward takes the pairs in windows of one binding. Returns 0 when not even one vertex fits."""
    pairs = int(round(float(pairs_per_pixel) * width * height * supersample ** 2))
    window = None if max_binding is None else int(max_binding) // (4 * _consts()["nstat"])

    def fits(n):
        bufs = training_buffers(n, int(round(n * float(triangles_per_vertex))), sh_degree, width, height, pairs,
                                supersample, views=views, pair_window=window, max_binding=max_binding)
        if max_binding is not None and any(b > (max_buffer if name in CHUNKED else max_binding)
                                           for _, name, b in bufs):
            return False
        return sum(b for _, _, b in bufs) <= memory_bytes

    lo, hi = 0, 1
    while fits(hi):
        lo, hi = hi, hi * 2
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (mid, hi) if fits(mid) else (lo, mid)
    return lo


def available_bytes(ctx):
    """The memory ``ctx``'s device may use, where it can be known: a CPU adapter's (llvmpipe's)
    is this machine's available memory (``MemAvailable``, /proc/meminfo). None elsewhere: wgpu
    reports no GPU's memory."""
    if not getattr(ctx, "is_cpu", False):
        return None
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def check_fits(ctx, num_vertices, num_triangles, sh_degree, cameras):
    """Before a trainer makes any buffer: the one-line error when training this model on these
    training ``cameras`` needs more than the device has (where that is known:
    :func:`available_bytes`). The need is :func:`training_bytes` at the largest view, one
    tile-triangle pair per pixel and every view's image on the device; densification may grow
    it later, up to the vertex cap."""
    avail = available_bytes(ctx)
    if avail is None or not cameras:
        return
    w, h = max(c.width for c in cameras), max(c.height for c in cameras)
    need = training_bytes(num_vertices, num_triangles, sh_degree, w, h, w * h, views=len(cameras),
                          max_binding=int(ctx.limits["max-storage-buffer-binding-size"]))["total"]
    if need > avail:
        raise ValueError(f"device memory: training {num_vertices:,} vertices and {num_triangles:,} triangles on "
                         f"{len(cameras)} views of {w}x{h} needs about {need / 2**30:.1f} GiB, but {ctx.name} has "
                         f"{avail / 2**30:.1f} GiB available (this machine's free memory); use --downscale, fewer "
                         f"initial points (e.g. init_points_share = 0.5 in a --config file) or a GPU")


__all__ = ["available_bytes", "check_fits", "CHUNKED", "FAMILIES", "training_buffers", "training_bytes", "largest_model"]
