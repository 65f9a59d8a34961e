"""The optional normal loss (method.md: ``0.05 [indoor 0.025] * mean(1 - <N_rendered, N_prior>)``
for it > 5000, scaled with ``quick``), on the device and as a float64 twin.

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
(:class:`~tsplus_wgpu.backward.SegmentSum`) gathers them per shared vertex, and
``normal_accumulate.wgsl`` adds ``weight x`` that into the trainer's gradient buffers before
Adam. No host round trip beyond the forward pass's own size readbacks. A dedicated
normal-composite rasterizer pair would save the second sort/bin, but would duplicate the
most delicate kernels (and their budget handling on lavapipe) for a loss that is optional.

The normal image is rendered at the training resolution (s = 1) even while the colour image
is supersampled: the prior has that resolution, and the loss is a regulariser.

Twins: :func:`normal_model_reference`, :func:`normal_render_reference`,
:func:`normal_loss_reference` (the whole gradient, float64; ``paths`` drops either path for the
tests' mutation check), :func:`normal_loss_value_reference` (the loss alone, for finite
differences).
"""

from __future__ import annotations

import numpy as np

from .. import reference as ref
from .. import reference_backward as rb
from ..backward import SegmentSum
from ..device_model import DeviceModel
from ..gpu import Stage
from ..types import Camera, TriangleModel

SH_C0 = ref.SH_C0
#: A prior pixel is used when its decoded normal's length is in this range (then normalised):
#: grey (128,128,128) = the zero vector, black = (-1,-1,-1) of length 1.73 and NaN are left out.
PRIOR_MIN_LENGTH = 0.5
PRIOR_MAX_LENGTH = 1.5
PATHS = ("alpha", "normal")


def _groups(n):
    return max(1, (int(n) + 255) // 256)


# ---------------------------------------------------------------------- priors

def prepare_prior(normals, alpha=None):
    """A raw normal map ``[H, W, 3]`` (decoded to [-1, 1]) -> ``(unit prior [H, W, 3] float32,
    valid [H, W] bool)``: pixels whose length is outside [0.5, 1.5], not finite, or whose
    ``alpha`` (optional ``[H, W]``) is 0 are invalid (prior 0 there)."""
    n = np.asarray(normals, np.float64)
    if n.ndim != 3 or n.shape[2] != 3:
        raise ValueError(f"normal map: expected shape [H, W, 3], got {n.shape}")
    finite = np.all(np.isfinite(n), axis=2)
    n = np.where(finite[..., None], n, 0.0)
    length = np.linalg.norm(n, axis=2)
    valid = finite & (length >= PRIOR_MIN_LENGTH) & (length <= PRIOR_MAX_LENGTH)
    if alpha is not None:
        valid &= np.asarray(alpha) > 0
    unit = np.where(valid[..., None], n / np.where(valid, length, 1.0)[..., None], 0.0)
    return unit.astype(np.float32), valid


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


# ---------------------------------------------------------------------- twins

def triangle_normals_reference(positions, triangles, camera: Camera):
    """Per triangle ``(n [M, 3] camera space, facing the camera; u [M, 3] world unit normal;
    length [M] = |cross|; sign [M] = +-1)`` float64 (twin of ``common/normal.wgsl``)."""
    x = np.asarray(positions, np.float64)[np.asarray(triangles, np.int64)]         # [M, 3, 3]
    e = np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0])
    length = np.sqrt(np.einsum("mi,mi->m", e, e))
    ok = length > 0
    u = np.where(ok[:, None], e / np.where(ok, length, 1.0)[:, None], 0.0)
    R, t = camera.R, camera.t
    n = u @ R.T
    c = x.mean(axis=1) @ R.T + t
    sign = np.where(np.einsum("mi,mi->m", n, c) > 0, -1.0, 1.0)
    return sign[:, None] * n, u, np.where(ok, length, 0.0), sign


def normal_model_reference(model: TriangleModel, camera: Camera) -> TriangleModel:
    """The unshared normal render model (twin of ``normal_model.wgsl``): corners ``3t + k`` at
    the triangles' vertices, SH DC ``n_t / (2 SH_C0)`` (degree 0), opacity ``o_T``."""
    tri = model.triangles
    m = tri.shape[0]
    n, _, _, _ = triangle_normals_reference(model.positions, tri, camera)
    pos = model.positions[tri].reshape(3 * m, 3)
    sh = np.repeat(n / (2.0 * SH_C0), 3, axis=0)[:, None, :]
    op = np.repeat(model.opacity[tri].min(axis=1), 3)
    return TriangleModel(pos, np.arange(3 * m).reshape(m, 3), sh, op)


def normal_render_reference(model: TriangleModel, camera: Camera, sigma, near=0.01):
    """``(N [H, W, 3], T [H, W])``: the alpha-blended camera-space normal and the final
    transmittance, float64, through :func:`tsplus_wgpu.reference.render` of the normal model."""
    r = ref.render(normal_model_reference(model, camera), camera, sigma, (0.0, 0.0, 0.0), near)
    return 2.0 * r.image - (1.0 - r.transmittance)[..., None], r.transmittance


def normal_loss_value_reference(model, camera, sigma, prior, valid, weight=1.0, near=0.01):
    """``weight * mean over valid pixels of (1 - <N, P>)`` (0 when no pixel is valid), float64."""
    v = np.asarray(valid, bool)
    if not v.any():
        return 0.0
    n, _ = normal_render_reference(model, camera, sigma, near)
    return float(weight) * float(np.mean(1.0 - np.einsum("pc,pc->p", n[v], np.asarray(prior, np.float64)[v])))


def normal_loss_reference(model: TriangleModel, camera: Camera, sigma, prior, valid, weight=1.0, near=0.01,
                          paths=PATHS):
    """Float64 twin of the whole normal-loss gradient (normal_model -> forward -> backward ->
    normal_backward -> per-vertex sum -> normal_accumulate).

    Args:
        model, camera, sigma, near: as for :func:`tsplus_wgpu.reference.render`.
        prior, valid: from :func:`prepare_prior`.
        weight: the loss weight.
        paths: which gradient paths to keep: ``"alpha"`` (through the blending weights: the
            corner positions and o_T) and ``"normal"`` (through the 3D normal). Both for the
            true gradient; one alone only for tests that show the other matters.

    Returns:
        ``(loss, v_positions [N, 3], v_opacity [N])`` float64.
    """
    bad = set(paths) - set(PATHS)
    if bad:
        raise ValueError(f"paths: unknown {sorted(bad)}; expected a subset of {PATHS}")
    tri = model.triangles
    m, nv = tri.shape[0], model.num_vertices
    v_pos = np.zeros((nv, 3))
    v_op = np.zeros(nv)
    vi, vt, cnt = normal_cotangents(prior, valid)
    if cnt == 0 or m == 0:
        return 0.0, v_pos, v_op
    um = normal_model_reference(model, camera)
    r = ref.render(um, camera, sigma, (0.0, 0.0, 0.0), near)
    n_img = 2.0 * r.image - (1.0 - r.transmittance)[..., None]
    v = np.asarray(valid, bool)
    loss = float(weight) * float(np.mean(1.0 - np.einsum("pc,pc->p", n_img[v], np.asarray(prior, np.float64)[v])))
    g = rb.backward(um, camera, sigma, vi, vt, (0.0, 0.0, 0.0), near)
    corner = np.zeros((m, 3, 3))
    if "alpha" in paths:
        corner += g.v_positions.reshape(m, 3, 3)
        v_ot = g.v_opacity.reshape(m, 3).sum(axis=1)
        best = rb.min_vertex(model.opacity, tri)
        np.add.at(v_op, tri[np.arange(m), best], v_ot)
    if "normal" in paths:
        v_n = g.v_sh[:, 0, :].reshape(m, 3, 3).sum(axis=1) / (2.0 * SH_C0)        # [M, 3]
        _, u, length, sign = triangle_normals_reference(model.positions, tri, camera)
        ok = length > 0
        v_u = sign[:, None] * (v_n @ camera.R)                                     # R^T v_n
        v_e = (v_u - u * np.einsum("mi,mi->m", u, v_u)[:, None]) / np.where(ok, length, 1.0)[:, None]
        v_e[~ok] = 0.0
        x = model.positions[tri]
        g1 = np.cross(x[:, 2] - x[:, 0], v_e)
        g2 = np.cross(v_e, x[:, 1] - x[:, 0])
        corner += np.stack([-(g1 + g2), g1, g2], axis=1)
    np.add.at(v_pos, tri.ravel(), corner.reshape(-1, 3))
    return loss, float(weight) * v_pos, float(weight) * v_op


# ---------------------------------------------------------------------- device

class NormalModel(Stage):
    stage = "normal_model"

    def __call__(self, enc, params, positions, triangles, opacity, corner_positions, corner_sh, corner_opacity, m,
                 profiler=None):
        self.dispatch(enc, _groups(m), dict(np_=params, positions=positions, triangles=triangles, opacity=opacity,
                                            corner_positions=corner_positions, corner_sh=corner_sh,
                                            corner_opacity=corner_opacity), profiler)


class NormalBackward(Stage):
    stage = "normal_backward"

    def __call__(self, enc, params, positions, triangles, opacity, v_corner_positions, v_corner_sh, v_corner_opacity,
                 corner_vals, m, profiler=None):
        self.dispatch(enc, _groups(m), dict(np_=params, positions=positions, triangles=triangles, opacity=opacity,
                                            v_corner_positions=v_corner_positions, v_corner_sh=v_corner_sh,
                                            v_corner_opacity=v_corner_opacity, corner_vals=corner_vals), profiler)


class NormalAccumulate(Stage):
    stage = "normal_accumulate"

    def __call__(self, enc, params, vertex_sums, v_positions, v_opacity, n, profiler=None):
        self.dispatch(enc, _groups(n), dict(np_=params, vertex_sums=vertex_sums, v_positions=v_positions,
                                            v_opacity=v_opacity), profiler)


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

    def _params(self, camera, weight):
        R, t = camera.R, camera.t
        return self.model_k.uniform("NormalParams", rot0=[*R[0], t[0]], rot1=[*R[1], t[1]], rot2=[*R[2], t[2]],
                                    num_triangles=self.m, num_vertices=self.n, weight=float(weight))

    def run(self, camera, sigma, near, positions, triangles, opacity, target, v_positions, v_opacity, weight):
        """Add ``weight x`` the normal loss's gradient for ``camera`` into ``v_positions``
        (``[N, 3]`` f32) and ``v_opacity`` (``[N]``, w.r.t. the activated opacity). ``positions``,
        ``triangles``, ``opacity``: the shared model's device buffers; ``target``: from
        :meth:`target`. Returns the forward result of the normal render (``image`` = C,
        ``transmittance`` = T: ``N = 2 C - (1 - T)``)."""
        if self.dm is None:
            raise RuntimeError("NormalLoss.set_topology was not called")
        c, r = self.ctx, self.renderer
        params = self._params(camera, weight)
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
        :func:`normal_loss_reference`'s definition, computed on the device (the loss from the
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
    k.model_k(enc, k._params(camera, 1.0), dm.buffers["positions"], dm.buffers["triangles"], dm.buffers["opacity"],
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


__all__ = ["NormalLoss", "NormalModel", "NormalBackward", "NormalAccumulate", "prepare_prior", "normal_cotangents",
           "normal_error", "triangle_normals_reference", "normal_model_reference", "normal_render_reference",
           "normal_loss_value_reference", "normal_loss_reference", "loss_from_render", "render_normals", "PRIOR_MIN_LENGTH",
           "PRIOR_MAX_LENGTH"]


def bench_step_cost(size="tiny", reps=10, warm=600, adapter=None):
    """Per-step cost of the normal loss: a quick-preset trainer on the procedural scene
    (``size``, its true normal maps, topology off so the mesh stays fixed) trained to ``warm``
    of 3000 iterations (normal loss on from 501), then ``reps`` pairs of steps with and without
    the normal loss, interleaved (so load from other processes hits both alike). Returns
    ``dict(with_ms, without_ms, cost_ms, triangles, vertices)`` (medians, host wall time with a
    queue wait after each step)."""
    import time

    from ..data import load_procedural
    from ..data.procedural import normal_maps
    from ..renderer import Renderer
    from .trainer import TrainConfig, Trainer
    sc = load_procedural(size)
    pri = [prepare_prior(m) if v in sc.train_indices else None for v, m in enumerate(normal_maps(sc))]
    r = Renderer(adapter)
    t = Trainer(sc, TrainConfig(iterations=3000, quick=True, topology=False, background=sc.background), renderer=r,
                normals=pri)
    t.train(progress=False, until=warm, log_every=0)
    maps, c = t.normal_maps, r.ctx
    times = {True: [], False: []}
    for _ in range(int(reps)):
        for on in (True, False):
            t.normal_maps = maps if on else None
            c.wait()
            t0 = time.perf_counter()
            t.step()
            c.wait()
            times[on].append(time.perf_counter() - t0)
    t.normal_maps = maps
    w, wo = 1e3 * float(np.median(times[True])), 1e3 * float(np.median(times[False]))
    return dict(size=size, with_ms=w, without_ms=wo, cost_ms=w - wo, triangles=t.m, vertices=t.n,
                adapter=r.adapter_name)


if __name__ == "__main__":   # python -m tsplus_wgpu.train.normals [tiny|small|demo] [pairs]
    import sys
    res = bench_step_cost(sys.argv[1] if len(sys.argv) > 1 else "tiny", int(sys.argv[2]) if len(sys.argv) > 2 else 10)
    print(f"{res['adapter']}: procedural:{res['size']} ({res['triangles']} triangles, {res['vertices']} vertices): "
          f"step {res['without_ms']:.1f} ms without the normal loss, {res['with_ms']:.1f} ms with "
          f"(+{res['cost_ms']:.1f} ms; medians of interleaved steps)")
