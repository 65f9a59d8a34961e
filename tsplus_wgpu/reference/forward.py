"""Float64 NumPy twin of the forward rasterizer: the same model and conventions as the
WGSL kernels, written for clarity. Tests compare every kernel against it.

The model (method.md):
  * vertex colour ``c_v = max(0, SH(dir_v) + 0.5)``, dir_v the unit vector from the
    camera centre to the vertex (zero at the centre itself: DC only);
  * a triangle with any vertex at camera z <= near is not drawn; nor one whose
    opacity o_T = min of its vertices' is below 1/255 (it could never reach alpha 1/255),
    nor one numerically degenerate on screen (2*area / perimeter^2 < 1e-6);
  * window ``I(p) = max(0, phi(p)/phi(s))^sigma`` with ``phi(p)/phi(s) = min_k e_k(p)``,
    ``e_k(p) = 1 + g_k . (p - s)``, s the incenter, g_k = -n_k / r;
  * colour at p: screen-space barycentric interpolation, b_k = e_k(p) len_k / perimeter;
  * ``alpha = min(0.99, o_T I)``; skip alpha < 1/255; front to back by centroid camera z
    (ties in triangle order); stop before T would fall below 1e-4; out = C + T * bg.
"""

from __future__ import annotations

from ..sh import SH_C1, SH_C2, SH_C3, sh_basis, vertex_colors  # noqa: F401  (the twin's namespace)
from ..types import SH_C0, Camera, TriangleModel, check_render_args  # noqa: F401
from .bin import bin_pairs, tile_overlaps  # noqa: F401  (the twin's namespace)
from .project import (ALPHA_MAX, ALPHA_MIN, BIN_MARGIN, MIN_THINNESS, T_MIN, TILE,  # noqa: F401
                      Projection, projection, projection_from_records)
from .sort import depth_order
from .blend import RenderResult, rasterize_forward  # noqa: F401  (the twin's namespace)


def render(model: TriangleModel, camera: Camera, sigma, background=(0.0, 0.0, 0.0), near=0.01,
           ambiguity_tol=1e-4):
    """Float64 forward render; same arguments and outputs as ``Renderer.forward``.

    Besides ``image``, ``transmittance`` and ``max_weight`` the result carries
    ``ambiguous``: pixels where a discrete decision (inside/outside an edge, the 1/255
    skip, the T < 1e-4 stop) was within ``ambiguity_tol`` (relative) of flipping, where
    float32 arithmetic may legitimately decide the other way; and ``f32_bound``, a
    first-order estimate of the image error that float32 rounding of the projected
    vertices causes (large only where the window is steep: sigma < 1 near an edge, or
    thin triangles).
    """
    sigma, bg, near = check_render_args(sigma, background, near)
    if not isinstance(model, TriangleModel):
        raise ValueError("model: expected a TriangleModel")
    if not isinstance(camera, Camera):
        raise ValueError("camera: expected a Camera")
    proj = projection(model, camera, sigma, near)
    return rasterize_forward(proj, depth_order(proj), camera.width, camera.height, sigma, bg, ambiguity_tol)


blend = rasterize_forward   # the name tests and tools know


