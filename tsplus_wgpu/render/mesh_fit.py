"""Vertex colours of an opaque mesh fitted to photos: the colours an engine should draw.

A depth-tested, vertex-coloured mesh is *linear* in its colours: each pixel sample shows
``b0 c_a + b1 c_b + b2 c_c``, where ``(a, b, c)`` is the front triangle at the sample and
``b`` its perspective-correct barycentric coordinates, and a pixel is the mean of its
``s x s`` samples. So for fixed geometry the colours that best reproduce the training photos
solve a sparse linear least-squares problem, exactly:

    minimise  sum_views || A_v c - (y_v - bg (1 - coverage_v)) ||^2  +  lam || c - c0 ||^2

``A_v`` has a row per pixel and three entries per covered sample. ``c0`` is the prior
colour (the SH DC term) and ``lam`` (:data:`PRIOR_WEIGHT`, in pixels) only decides
vertices that no pixel constrains. It is solved per channel by Jacobi-preconditioned
conjugate gradients started at ``c0``, then clipped to [0, 1].

Why it matters: the trainer's colour is a degree-3 SH function whose DC term is its mean
over the *whole sphere*, while the photos see each vertex from a narrow cone; dropping the
higher bands at export (an engine draws one colour per vertex) loses 1-2 dB on real
captures. Fitting the colours to the photos through the exported geometry recovers it.

The front triangle of every sample comes from the :class:`MeshRenderer` itself (the mesh
drawn un-indexed with the triangle id as a flat colour), so the fit sees exactly what
``tsplus eval`` draws; the barycentric coordinates are the float64 intersection of the
sample's ray with that triangle (what perspective-correct interpolation computes).
"""

from __future__ import annotations

import numpy as np

from ..types import Camera

#: prior weight (in pixels of evidence) pulling a vertex towards its SH DC colour
PRIOR_WEIGHT = 0.01
#: samples per fitted view at most (supersampling is reduced to stay under it): 524,288, so
#: 960x540 gets 1x1 and 480x270 2x2. At 1 << 21 a fit of office at 960x540 drew 2x2 samples
#: and took 51.6 s against 14.5 at 1x1 (2-core EPYC) for the same held-out PSNR (23.768 and
#: 23.777 dB); cup at 800x600 and fox at 540x960 alike (docs/measurements.md)
MAX_SAMPLES = 1 << 19
ID_BASE = 2048      # triangle id = r + ID_BASE * g: both channels stay exact in float32 interpolation


def id_mesh(mesh_renderer, positions, triangles):
    """The id pass's mesh, uploaded once (:meth:`MeshRenderer.upload`) for every view it is
    drawn from: ``triangles`` un-indexed, each in the flat colour that encodes its number."""
    tri = np.asarray(triangles, np.int64).reshape(-1, 3)
    m = len(tri)
    if m >= ID_BASE * ID_BASE:
        raise ValueError(f"triangles: {m} is over the {ID_BASE * ID_BASE} the id pass can name")
    pos = np.asarray(positions, np.float32)[tri].reshape(-1, 3)
    k = np.arange(m, dtype=np.int64)
    ids = np.stack([k % ID_BASE, k // ID_BASE, np.zeros(m, np.int64)], 1).astype(np.float32)
    return mesh_renderer.upload((pos, np.arange(3 * m, dtype=np.int64).reshape(-1, 3), np.repeat(ids, 3, axis=0)))


def triangle_ids(mesh_renderer, positions, triangles, camera: Camera, near, uploaded=None) -> np.ndarray:
    """``[H, W]`` int64: the triangle the depth-tested mesh renderer draws at each pixel
    centre of ``camera`` (-1: none). Triangles with a vertex at ``z <= near`` are not drawn,
    as in :meth:`MeshRenderer.render`. ``uploaded``: :func:`id_mesh` of the same mesh, made
    here when None (pass it when drawing one mesh from several views)."""
    return ids_and_depth(mesh_renderer, positions, triangles, camera, near, uploaded)[0]


def ids_and_depth(mesh_renderer, positions, triangles, camera: Camera, near, uploaded=None):
    """``(ids [H, W] int64, depth [H, W] float32)``: :func:`triangle_ids` and the camera z of the
    triangle drawn at each pixel centre (0 where none), from the same id pass."""
    if uploaded is None:
        uploaded = id_mesh(mesh_renderer, positions, triangles)
    res = mesh_renderer.render(uploaded, camera, near=near)
    img = res.image                       # float32: whole numbers below ID_BASE, exact
    out = np.rint(img[..., 0]).astype(np.int64) + ID_BASE * np.rint(img[..., 1]).astype(np.int64)
    drawn = res.coverage > 0
    out[~drawn] = -1
    return out, np.where(drawn, res.depth, 0.0).astype(np.float32)


def _drawn(ids, count):
    """``(unique [U], inverse [K])``: the distinct values of ``ids`` (in ``[0, count)``) in
    increasing order and each id's index among them; a mark and a running count, no sort."""
    mark = np.zeros(count, bool)
    mark[ids] = True
    return np.flatnonzero(mark), (np.cumsum(mark) - 1)[ids]


def _cross(a, b):
    return np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                     a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], 1)


def barycentrics(positions, triangles, camera: Camera, ids, rows, cols) -> np.ndarray:
    """``[K, 3]`` float64 barycentric coordinates of the pixel centres ``(rows, cols)`` on the
    triangles ``ids`` [K]: where each centre's ray meets the triangle's plane (clipped to
    the triangle: a centre the rasteriser counted inside lies on it to rounding).

    With the corners ``p0, p1, p2`` in the camera's frame, ``e1 = p1 - p0``, ``e2 = p2 - p0``
    and the ray ``t d``, ``d = (x, y, 1)``, the ray meets the plane at ``b1 = d.(e2 x -p0) /
    d.(e2 x e1)`` and ``b2 = d.(-p0 x e1) / d.(e2 x e1)`` (Cramer's rule): three vectors a
    triangle, made once for each triangle drawn, then three dot products a sample."""
    ids = np.asarray(ids, np.int64)
    tri_all = np.asarray(triangles, np.int64).reshape(-1, 3)
    if not len(ids):
        return np.zeros((0, 3))
    drawn, which = _drawn(ids, len(tri_all))
    p = np.asarray(positions, np.float64)[tri_all[drawn]] @ camera.R.T + camera.t     # [U, 3 corners, 3]
    s, e1, e2 = -p[:, 0], p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    planes = np.stack([_cross(e2, e1), _cross(e2, s), _cross(s, e1)], 1)[which]     # [K, (det, b1, b2), 3]
    x = (np.asarray(cols, np.float64) + 0.5 - camera.cx) / camera.fx
    y = (np.asarray(rows, np.float64) + 0.5 - camera.cy) / camera.fy
    dots = planes[:, :, 0] * x[:, None] + planes[:, :, 1] * y[:, None] + planes[:, :, 2]   # [K, 3]
    det = np.where(np.abs(dots[:, 0]) > 1e-300, dots[:, 0], 1e-300)
    b1, b2 = dots[:, 1] / det, dots[:, 2] / det
    b = np.clip(np.stack([1.0 - b1 - b2, b1, b2], 1), 0.0, None)
    return b / np.maximum(b.sum(1, keepdims=True), 1e-300)


def fit_supersample(camera: Camera, supersample):
    s = max(1, int(supersample))
    while s > 1 and camera.width * camera.height * s * s > MAX_SAMPLES:
        s -= 1
    return s


#: the six entries of a symmetric 3x3 block, and the block's nine from them
_PAIRS = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))
_BLOCK = np.array([[0, 3, 4], [3, 1, 5], [4, 5, 2]])


class NormalEquations:
    """``A^T A`` and ``A^T y`` of the colour fit (module docstring), summed over views. A pixel
    whose samples all lie on one triangle ``t`` (every covered pixel at 1x1 samples) is the row
    ``beta`` (the mean barycentric coordinates of its samples) on ``t``'s three vertices, so its
    ``beta beta^T`` adds to ``t``'s own 3x3 block: six sums a triangle (:attr:`blocks`). The pixels whose samples straddle
    triangles make a sparse ``A^T A`` of their own, summed view by view (:attr:`mixed`; most
    pixels where triangles are about a pixel wide). :meth:`ata` assembles the sparse ``[N, N]``
    matrix; ``A^T y`` is a sum over samples."""

    def __init__(self, triangles, num_vertices):
        self.triangles = np.asarray(triangles, np.int64).reshape(-1, 3)
        self.n = int(num_vertices)
        self.blocks = np.zeros((len(self.triangles), 6))
        self.aty = np.zeros((self.n, 3))
        self.mixed = None                  # the straddling pixels' A^T A (CSR), summed over the views

    def add_view(self, mesh_renderer, positions, camera: Camera, image, near, supersample=2,
                 background=(0.0, 0.0, 0.0), uploaded=None):
        """Adds one view at ``s x s`` samples a pixel (reduced to :data:`MAX_SAMPLES`); returns
        its coverage ``[H, W]``. ``uploaded`` as in :func:`triangle_ids`."""
        from scipy.sparse import csr_matrix
        tri, m = self.triangles, len(self.triangles)
        w, h = camera.width, camera.height
        s = fit_supersample(camera, supersample)
        cam = camera if s == 1 else Camera(w * s, h * s, camera.fx * s, camera.fy * s, camera.cx * s,
                                           camera.cy * s, camera.world_to_camera)
        ids = triangle_ids(mesh_renderer, positions, tri, cam, near, uploaded)
        r, c = np.nonzero(ids >= 0)
        tid = ids[r, c]
        b = barycentrics(positions, tri, cam, tid, r, c) / (s * s)            # each sample's share of A's row
        pix = (r // s) * w + c // s
        cover = np.bincount(pix, minlength=h * w) / (s * s)
        y = np.asarray(image, np.float64).reshape(-1, 3) - np.outer(1.0 - cover, np.asarray(background, np.float64))
        verts = tri[tid].ravel()
        for ch in range(3):                # A^T y: every sample's share of its pixel's colour
            self.aty[:, ch] += np.bincount(verts, weights=(b * y[pix, ch, None]).ravel(), minlength=self.n)
        grid = ids.reshape(h, s, w, s).transpose(0, 2, 1, 3).reshape(h * w, s * s)
        top = grid.max(axis=1)
        low = np.where(grid >= 0, grid, m).min(axis=1)
        one = (top >= 0) & (low == top)                                       # pixels on a single triangle
        pure = one[pix]
        beta = np.stack([np.bincount(pix[pure], weights=b[pure, k], minlength=h * w) for k in range(3)], 1)
        beta, t1 = beta[one], top[one]
        for j, (k, q) in enumerate(_PAIRS):
            self.blocks[:, j] += np.bincount(t1, weights=beta[:, k] * beta[:, q], minlength=m)
        if not pure.all():
            mix = ~pure
            rows = _drawn(pix[mix], h * w)[1]
            a = csr_matrix((b[mix].ravel(), (np.repeat(rows, 3), tri[tid[mix]].ravel())),
                           shape=(int(rows.max()) + 1, self.n))
            prod = (a.T @ a).tocsr()
            self.mixed = prod if self.mixed is None else self.mixed + prod
        return cover.reshape(h, w)

    def ata(self):
        """The sparse ``[N, N]`` ``A^T A`` (CSR) of the views added."""
        from scipy.sparse import coo_matrix
        used = np.flatnonzero(self.blocks.any(axis=1))
        t = self.triangles[used]
        out = coo_matrix((self.blocks[used][:, _BLOCK.ravel()].ravel(),
                          (np.repeat(t, 3, axis=1).ravel(), np.tile(t, (1, 3)).ravel())), shape=(self.n, self.n)).tocsr()
        return out if self.mixed is None else (out + self.mixed).tocsr()


def view_system(mesh_renderer, positions, triangles, camera: Camera, image, near, supersample=2,
                background=(0.0, 0.0, 0.0), uploaded=None):
    """One view's normal-equation terms ``(AtA [N, N] sparse, Aty [N, 3], coverage [H, W])``
    at ``s x s`` samples per pixel (reduced to :data:`MAX_SAMPLES`); ``uploaded`` as in
    :func:`triangle_ids`."""
    eq = NormalEquations(triangles, len(positions))
    cover = eq.add_view(mesh_renderer, positions, camera, image, near, supersample, background, uploaded)
    return eq.ata(), eq.aty, cover


def fit_vertex_colors(positions, triangles, cameras, images, prior, near, mesh_renderer=None, supersample=2,
                      background=(0.0, 0.0, 0.0), prior_weight=PRIOR_WEIGHT, tol=1e-6, max_iter=1000,
                      progress=None):
    """Least-squares vertex colours of the opaque mesh ``(positions, triangles)`` against
    ``images`` seen by ``cameras`` (module docstring). ``prior``: ``[N, 3]`` colours for
    vertices the photos do not decide (the SH DC). Returns ``(colors [N, 3] in [0, 1],
    info dict: views, observed vertices, residual RMS before and after on the fitted views,
    conjugate-gradient iterations)``."""
    from scipy.sparse import diags
    from scipy.sparse.linalg import cg

    from .mesh_renderer import MeshRenderer
    mr = mesh_renderer or MeshRenderer()
    pos = np.asarray(positions, np.float64)
    tri = np.asarray(triangles, np.int64).reshape(-1, 3)
    c0 = np.clip(np.asarray(prior, np.float64), 0.0, 1.0)
    n = len(pos)
    if n == 0 or len(tri) == 0:
        return c0.copy(), dict(views=0, observed=0, iterations=0)
    eq = NormalEquations(tri, n)
    uploaded = id_mesh(mr, pos, tri)
    for k, (cam, img) in enumerate(zip(cameras, images)):
        eq.add_view(mr, pos, cam, img, near, supersample, background, uploaded)
        if progress is not None:
            progress(k + 1)
    ata, aty = eq.ata(), eq.aty
    diag = ata.diagonal()
    lhs = (ata + diags(np.full(n, float(prior_weight)))).tocsr()
    rhs = aty + prior_weight * c0
    precond = diags(1.0 / (diag + prior_weight))
    out, iters = np.empty_like(c0), []
    for ch in range(3):
        count = [0]
        def tick(_x, count=count):
            count[0] += 1
        x, _ = cg(lhs, rhs[:, ch], x0=c0[:, ch], rtol=tol, maxiter=max_iter, M=precond, callback=tick)
        out[:, ch] = x
        iters.append(count[0])
    colors = np.clip(out, 0.0, 1.0)

    def quad(c):   # sum over the fitted pixels of |A c - y|^2 up to the constant y^T y
        return float(np.sum(c * (ata @ c)) - 2 * np.sum(c * aty))
    return colors, dict(views=len(cameras), observed=int((diag > 0).sum()), iterations=max(iters),
                        objective_prior=quad(c0), objective_fit=quad(colors))
