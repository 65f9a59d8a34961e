"""The optional normal loss (method.md: ``0.05 [indoor 0.025] * mean(1 - <N_rendered, N_prior>)``
for it > 5000, scaled with ``quick``), on the device (float64 twin: :mod:`tsplus_wgpu.reference.normals`).

Definitions (method.md leaves them open; these are ours):

* ``N_rendered(p) = sum_i w_i(p) n_i``: the triangles' normals alpha-blended with the colour
  image's own weights ``w_i = alpha_i T_i`` (same window, opacity, depth order and early stop),
  background 0, *not* renormalised (as the authors' code, and so that a pixel the mesh does
  not cover is penalised: ``1 - <0, P> = 1``). ``n_i`` is the unit normal of triangle i in
  camera space (OpenCV: x right, y down, z forward), ``normalize(cross(B - A, C - A))``
  oriented to face the camera (``<n, x_cam> <= 0`` on the triangle's plane); the orientation
  is piecewise constant and has no derivative. A zero-area triangle has ``n = 0``.
* ``N_prior(p)``: the normal map, normalised; pixels without a usable prior (decoded length
  outside [0.5, 1.5], not finite, or alpha 0) are left out of the mean. The mean is over the
  view's usable pixels.

So ``L = weight / |V| * sum_{p in V} (1 - <N(p), P(p)>)``.

The gradient has two paths, and both are kept (the authors' code keeps only the first; see
method.md, "Defects"):

1. the blending weights: ``w_i`` depends on the 2D vertices (window, incenter, inradius) and on
   ``o_T``: this is the existing backward pass, unchanged;
2. the 3D normal: ``n_i`` depends on the three vertex positions through the cross product and
   its normalisation.

How (why this shape): the loss is computed by rendering a second, *unshared* model with the
verified forward kernels. ``normal_model.wgsl`` gives every triangle three private corners at
its vertices' positions, each carrying the triangle's normal as the colour ``0.5 + n / 2``
(SH degree 0, so the colour clamp ``max(0, .)`` never bites) and the opacity ``o_T``. With the
same camera, sigma and near plane, the projection, culling, depth order and so every ``w_i``
are those of the colour image, and the black-background render is
``C = sum_i w_i (0.5 + n_i / 2) = 0.5 (1 - T) + N / 2``, i.e. ``N = 2 C - (1 - T)``.
``dL/dC = -2 P / |V|`` and ``dL/dT = -sum_c P_c / |V|`` depend only on the prior, so each
view's cotangent image is uploaded once. The unchanged backward pass of the unshared model
gives per-corner position, colour and opacity gradients; ``normal_backward.wgsl`` chains the
colour gradients to the triangle normal and through ``normalize(cross(.))`` to the vertices,
adds the corners' position gradients and routes the opacity gradient to the vertex holding
the minimum; the deterministic segmented sum over corners sorted by vertex
(:class:`~tsplus_wgpu.kernels.reduce.SegmentSum`) gathers them per shared vertex, and
``normal_accumulate.wgsl`` adds ``weight x`` that into the trainer's gradient buffers before
Adam. No host round trip beyond the forward pass's own size readbacks. A dedicated
normal-composite rasterizer pair would save the second sort/bin, but would duplicate the
most delicate kernels (and their budget handling on lavapipe) for a loss that is optional.

The normal image is rendered at the training resolution (s = 1) even while the colour image
is supersampled: the prior has that resolution, and the loss is a regulariser.

Twins (:mod:`tsplus_wgpu.reference.normals`): :func:`normal_model`, :func:`normal_backward`,
:func:`normal_accumulate` (one per kernel), :func:`normal_render`, :func:`normal_loss` (the whole
gradient, float64; ``paths`` drops either path for the tests' mutation check),
:func:`normal_loss_value` (the loss alone, for finite differences). The priors
(:func:`~tsplus_wgpu.data.normals.prepare_prior`) are scene data: :mod:`tsplus_wgpu.data.normals`.
"""

from __future__ import annotations

import numpy as np

from ..data.normals import PRIOR_MAX_LENGTH, PRIOR_MIN_LENGTH, prepare_prior
from ..kernels.normals import NormalAccumulate, NormalBackward, NormalModel
from ..kernels.reduce import SegmentSum
from ..render.device_model import DeviceModel, corner_spans
from ..types import TriangleModel


def normal_priors(scene, config, normals):
    """The trainer's normal maps, one entry per view of ``scene`` (None where a view has none):
    ``normals`` as given (a list or an object with ``maps``), else read from ``config.normals``
    (a folder). None when no view has one."""
    if normals is None and config.normals:
        from ..data.normals import load_normal_maps
        normals = load_normal_maps(scene, config.normals)
    if normals is None:
        return None
    maps = list(getattr(normals, "maps", normals))
    if len(maps) != len(scene.images):
        raise ValueError(f"normals: expected one entry per view ({len(scene.images)}), got {len(maps)}")
    return maps if any(m is not None for m in maps) else None


def normal_cotangents(prior, valid):
    """d (mean over valid pixels of 1 - <N, P>) / d (C, T) with ``N = 2 C - (1 - T)``:
    ``(v_image [H, W, 3], v_T [H, W], count)`` float64 (zero where invalid; count 0 gives
    zeros)."""
    p = np.asarray(prior, np.float64)
    v = np.asarray(valid, bool)
    cnt = int(v.sum())
    s = 1.0 / max(cnt, 1)
    vi = np.where(v[..., None], -2.0 * s * p, 0.0)
    vt = np.where(v, -s * p.sum(axis=2), 0.0)
    return vi, vt, cnt


def normal_error(rendered, prior, valid):
    """How far a rendered normal image is from a prior, over the prior's valid pixels:
    ``dict(loss = mean(1 - <N, P>), cos = mean cosine of normalize(N) and P,
    angle_deg = mean angle in degrees (N = 0 counts as 90), pixels)``."""
    n = np.asarray(rendered, np.float64)
    p = np.asarray(prior, np.float64)
    v = np.asarray(valid, bool)
    if not v.any():
        return dict(loss=float("nan"), cos=float("nan"), angle_deg=float("nan"), pixels=0)
    nv, pv = n[v], p[v]
    dot = np.einsum("pc,pc->p", nv, pv)
    length = np.linalg.norm(nv, axis=1)
    cos = np.where(length > 0, dot / np.where(length > 0, length, 1.0), 0.0)
    return dict(loss=float(np.mean(1.0 - dot)), cos=float(np.mean(cos)),
                angle_deg=float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))).mean()), pixels=int(v.sum()))


# ---------------------------------------------------------------------- device

class NormalLoss:
    """The normal loss's gradient on the device, added into caller-owned gradient buffers.

    ``set_topology`` (host, once per triangle list: init, topology edits) allocates the
    unshared model (a :class:`~tsplus_wgpu.DeviceModel` of 3M vertices, SH degree 0) and the
    corner order by vertex; :meth:`target` uploads a view's cotangent image once; :meth:`run`
    records ``normal_model``, the renderer's forward and backward of the unshared model, then
    ``normal_backward`` + segmented sum + ``normal_accumulate``.

    Args:
        renderer: the :class:`~tsplus_wgpu.Renderer` (its forward/backward are reused).
    """

    def __init__(self, renderer):
        self.renderer = renderer
        self.ctx = c = renderer.ctx
        self.model_k = NormalModel(c)
        self.back_k = NormalBackward(c)
        self.acc_k = NormalAccumulate(c)
        self.sum = SegmentSum(c, renderer.scratch, "normal_sum")
        self.m = self.n = 0
        self.dm = None

    def set_topology(self, triangles, num_vertices):
        c = self.ctx
        tri = np.asarray(triangles, np.int64).reshape(-1, 3)
        m, n = tri.shape[0], int(num_vertices)
        self.m, self.n = m, n
        flat = tri.reshape(-1)
        order = np.argsort(flat, kind="stable").astype(np.uint32)     # corners by vertex, in corner order
        self.keys = c.upload(flat[order].astype(np.uint32), "normal_keys")
        self.index = c.upload(order, "normal_index")
        bufs = dict(positions=c.buffer(36 * m, "normal_corner_positions"),
                    triangles=c.upload(np.arange(3 * m, dtype=np.uint32), "normal_corner_triangles"),
                    sh=c.buffer(36 * m, "normal_corner_sh"), opacity=c.buffer(12 * m, "normal_corner_opacity"))
        self.dm = DeviceModel(c, bufs, 3 * m, m, 1)
        # corner j of the unshared model is vertex j: already sorted, the backward skips its sort
        self.dm.corner_order = (bufs["triangles"], bufs["triangles"])
        self.dm.corner_spans = corner_spans(c, np.arange(3 * m), 3 * m)
        self.grads = dict(v_positions=c.buffer(36 * m, "normal_v_corner_positions"),
                          v_sh=c.buffer(36 * m, "normal_v_corner_sh"),
                          v_opacity=c.buffer(12 * m, "normal_v_corner_opacity"))
        self.corner_vals = c.buffer(48 * m, "normal_corner_vals")
        self.vertex_sums = c.buffer(16 * n, "normal_vertex_sums")

    def target(self, prior, valid, label="normal_target"):
        """Upload a view's cotangent image (``[H * W]`` vec4: dL/dC, dL/dT for weight 1).
        Returns ``(buffer, number of valid pixels)``."""
        vi, vt, cnt = normal_cotangents(prior, valid)
        h, w = vi.shape[:2]
        v = np.concatenate([vi.reshape(-1, 3), vt.reshape(-1, 1)], axis=1).astype(np.float32)
        return self.ctx.upload(v, label), cnt

    def params(self, camera, weight):
        """The ``NormalParams`` uniform of ``camera`` and the current topology."""
        return self.model_k.params(camera, self.m, self.n, weight)

    def run(self, camera, sigma, near, positions, triangles, opacity, target, v_positions, v_opacity, weight):
        """Add ``weight x`` the normal loss's gradient for ``camera`` into ``v_positions``
        (``[N, 3]`` f32) and ``v_opacity`` (``[N]``, w.r.t. the activated opacity). ``positions``,
        ``triangles``, ``opacity``: the shared model's device buffers; ``target``: from
        :meth:`target`. Returns the forward result of the normal render (``image`` = C,
        ``transmittance`` = T: ``N = 2 C - (1 - T)``)."""
        if self.dm is None:
            raise RuntimeError("NormalLoss.set_topology was not called")
        c, r = self.ctx, self.renderer
        params = self.params(camera, weight)
        enc = c.device.create_command_encoder()
        self.model_k(enc, params, positions, triangles, opacity, self.dm.buffers["positions"], self.dm.buffers["sh"],
                     self.dm.buffers["opacity"], self.m)
        c.queue.submit([enc.finish()])
        res = r.forward(self.dm, camera, sigma, (0.0, 0.0, 0.0), near)
        r.backward(res, target, read=False, out=self.grads)
        enc = c.device.create_command_encoder()
        self.back_k(enc, params, positions, triangles, opacity, self.grads["v_positions"], self.grads["v_sh"],
                    self.grads["v_opacity"], self.corner_vals, self.m)
        self.sum.record(enc, self.keys, self.index, self.corner_vals, 3 * self.m, 1, self.vertex_sums)
        self.acc_k(enc, params, self.vertex_sums, v_positions, v_opacity, self.n)
        c.queue.submit([enc.finish()])
        return res

    def gradients(self, model: TriangleModel, camera, sigma, prior, valid, weight=1.0, near=0.01):
        """Host convenience (tests, tools): ``(loss, v_positions [N, 3], v_opacity [N])`` of
        :func:`tsplus_wgpu.reference.normals.normal_loss`'s definition, computed on the device (the loss from the
        read-back normal render, in float64)."""
        c = self.ctx
        dm = DeviceModel.from_model(self.renderer, model)
        n = model.num_vertices
        self.set_topology(model.triangles, n)
        tgt, cnt = self.target(prior, valid)
        vp = c.upload(np.zeros(3 * n, np.float32), "normal_test_v_positions")
        vo = c.upload(np.zeros(n, np.float32), "normal_test_v_opacity")
        if cnt == 0:
            return 0.0, np.zeros((n, 3), np.float32), np.zeros(n, np.float32)
        res = self.run(camera, sigma, near, dm.buffers["positions"], dm.buffers["triangles"], dm.buffers["opacity"],
                       tgt, vp, vo, weight)
        loss = loss_from_render(res.image, res.transmittance, prior, valid, weight)
        return loss, c.read(vp, np.float32, 3 * n).reshape(n, 3), c.read(vo, np.float32, n)


def render_normals(renderer, model: TriangleModel, camera, sigma, near=0.01, loss=None):
    """The alpha-blended camera-space normal image ``N [H, W, 3]`` (float64) of a
    :class:`TriangleModel`, rendered on the device through the normal model (for metrics;
    ``loss``: a :class:`NormalLoss` to reuse; its topology is set to the model's)."""
    k = loss if loss is not None else NormalLoss(renderer)
    dm = DeviceModel.from_model(renderer, model)
    k.set_topology(model.triangles, model.num_vertices)
    c = k.ctx
    enc = c.device.create_command_encoder()
    k.model_k(enc, k.params(camera, 1.0), dm.buffers["positions"], dm.buffers["triangles"], dm.buffers["opacity"],
              k.dm.buffers["positions"], k.dm.buffers["sh"], k.dm.buffers["opacity"], k.m)
    c.queue.submit([enc.finish()])
    res = renderer.forward(k.dm, camera, sigma, (0.0, 0.0, 0.0), near)
    return 2.0 * res.image.astype(np.float64) - (1.0 - res.transmittance.astype(np.float64))[..., None]


def loss_from_render(image, transmittance, prior, valid, weight=1.0):
    """The normal loss from a normal-model render (``C``, ``T``), float64."""
    v = np.asarray(valid, bool)
    if not v.any():
        return 0.0
    n = 2.0 * np.asarray(image, np.float64) - (1.0 - np.asarray(transmittance, np.float64))[..., None]
    return float(weight) * float(np.mean(1.0 - np.einsum("pc,pc->p", n[v], np.asarray(prior, np.float64)[v])))


__all__ = ["NormalLoss", "NormalModel", "NormalBackward", "NormalAccumulate", "prepare_prior", "normal_priors",
           "normal_cotangents", "normal_error", "loss_from_render", "render_normals", "PRIOR_MIN_LENGTH",
           "PRIOR_MAX_LENGTH"]
