"""Colour detail at the end of training: the exported mesh subdivided where its triangles are
large on screen, so that the fitted vertex colours can carry the photos' texture
(:func:`colour_detail`).

An engine draws one colour per vertex, interpolated across each triangle: a triangle 16 pixels
wide in the training views shows a linear ramp over those 16 pixels, whatever the photos show
there. Splitting a triangle at its edge midpoints changes no surface (the midpoints lie on its
edges, so the depth-tested mesh covers the same pixels at the same depths) and gives the colour
fit (:mod:`tsplus_wgpu.render.mesh_fit`) more colours to solve for.

Whether that helps depends on the scene. Where the geometry is right (a desk, a printed cup)
the finer colours draw other viewpoints better; where it is off, sharper colours on the wrong
surface draw them worse. So the choice is validated on the training views themselves: every
:data:`VALIDATION_EVERY`-th training view is held back, each level's colours are fitted to the
other training views, and the level whose held-back views are drawn best, by a clear margin
(:func:`better`: a per-view gain :data:`SIGNIFICANCE` standard errors above zero), is kept
(none when no level is). Then the kept mesh's colours are fitted to all training views.

Levels are cumulative: level k splits the triangles whose longest edge is larger than
:data:`LEVEL_PX` [k-1] pixels at the nearest training camera (at the median focal length;
unit-free), largest first, within the detail budget: ``--detail-budget`` x the training
pixels, never below the training cap (``--vertex-budget`` x the training pixels) and under
``--max-vertices`` (:func:`~.final.detail_cap`).

Splitting is red-green refinement (:func:`split_triangles`): a chosen triangle is split in four
at its edge midpoints, a neighbour with two split edges is split in four as well, one with a
single split edge in two, so that no vertex lies on another triangle's edge (no T-junctions,
no cracks) and neighbours keep sharing their vertices.
"""

from __future__ import annotations

import numpy as np

#: every this-many-th training view is held back to validate the subdivision
VALIDATION_EVERY = 4
#: the fewest held-back views the validation needs (fewer training views: no subdivision)
MIN_VALIDATION_VIEWS = 2
#: the levels' size thresholds in pixels (longest edge at the nearest training camera)
LEVEL_PX = (16.0, 8.0, 4.0, 2.0)
#: no subdivision when the detail budget leaves room for fewer than this fraction more vertices (the
#: validation fits would cost minutes and could add nothing)
MIN_ROOM = 0.05
#: a level must beat the best so far by this many standard errors of its per-view gain (0: any
#: lower mean error on the held-back views). 2 measured against 0 on the four shared real scenes
#: (docs/measurements.md): never more than 0.01 dB worse held out, up to +0.61 dB on lund, and
#: the cup keeps 13,872 vertices instead of 59,999
SIGNIFICANCE = 2.0
#: samples per pixel side when the held-back views are drawn
VALIDATION_SUPERSAMPLE = 2


def split_triangles(triangles, red, num_vertices=None):
    """Red-green refinement of ``triangles`` [F, 3] (module docstring). ``red`` [F] bool: the
    triangles to split in four (the closure may add more). Returns ``(triangles [F', 3], edges
    [E, 2])``: the new vertex ``n + j`` (``n = num_vertices``, default the largest index + 1) is
    the midpoint of ``edges[j]``. Corners keep their order, so every new triangle faces the way
    its parent did."""
    tri = np.asarray(triangles, np.int64).reshape(-1, 3)
    red = np.asarray(red, bool).copy()
    f = len(tri)
    if f == 0 or not red.any():
        return tri.copy(), np.zeros((0, 2), np.int64)
    corner_edges = np.sort(np.stack([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]], 1), axis=2)  # edge k: k -> k+1
    base = int(tri.max()) + 1         # an edge (lo, hi) as the one number lo * base + hi: a 1-D unique, in the same order
    keys, inv = np.unique(corner_edges[..., 0] * base + corner_edges[..., 1], return_inverse=True)
    edges = np.stack([keys // base, keys % base], 1)
    inv = inv.reshape(f, 3)
    while True:                       # the closure: two split edges make a triangle red
        split = np.zeros(len(edges), bool)
        split[inv[red].ravel()] = True
        count = split[inv].sum(axis=1)
        grown = red | (count >= 2)
        if (grown == red).all():
            break
        red = grown
    n = int(tri.max()) + 1 if num_vertices is None else int(num_vertices)
    vid = np.full(len(edges), -1, np.int64)
    vid[split] = n + np.arange(int(split.sum()))
    mid = vid[inv]                                                                       # [F, 3]
    a, b, c = tri[red].T
    ab, bc, ca = mid[red].T
    parts = [tri[count == 0], np.stack([a, ab, ca], 1), np.stack([ab, b, bc], 1), np.stack([ca, bc, c], 1),
             np.stack([ab, bc, ca], 1)]
    for k in range(3):
        green = (count == 1) & (mid[:, k] >= 0)
        v0, v1, v2, m = tri[green, k], tri[green, (k + 1) % 3], tri[green, (k + 2) % 3], mid[green, k]
        parts += [np.stack([v0, m, v2], 1), np.stack([m, v1, v2], 1)]
    return np.concatenate(parts), edges[split]


def with_midpoints(values, edges):
    """``values`` [N, ...] followed by the midpoints (means) of ``edges``' two vertices."""
    values = np.asarray(values)
    return np.concatenate([values, 0.5 * (values[edges[:, 0]] + values[edges[:, 1]])])


def angular_size(positions, triangles, cameras):
    """``(edge [F], dist [F])``: each triangle's longest edge and its centroid's distance to the
    nearest of ``cameras``' centres (``edge / dist``: its angular size, in radians, seen face-on)."""
    p = np.asarray(positions, np.float64)[np.asarray(triangles, np.int64).reshape(-1, 3)]
    edge = np.linalg.norm(p - np.roll(p, 1, axis=1), axis=2).max(axis=1)
    cen = p.mean(axis=1)
    dist = np.full(len(p), np.inf)
    for c in cameras:                  # [F] at a time: no [F, C, 3] array
        dist = np.minimum(dist, np.linalg.norm(cen - c.center, axis=1))
    return edge, dist


def pixel_size(positions, triangles, cameras):
    """``[F]``: each triangle's longest edge in pixels at the nearest of ``cameras``' centres
    (:func:`angular_size` at their median focal length)."""
    edge, dist = angular_size(positions, triangles, cameras)
    focal = float(np.median([0.5 * (c.fx + c.fy) for c in cameras]))
    return edge / np.maximum(dist, 1e-12) * focal


def refine_level(num_vertices, triangles, size, threshold, room, triangle_room):
    """One level: split the triangles with ``size`` over ``threshold``, largest first, as many
    as keep the added vertices within ``room`` and the added triangles within
    ``triangle_room``. Returns ``(triangles, edges)`` or ``None`` when nothing is split."""
    cand = np.flatnonzero(size > threshold)
    if min(room, triangle_room / 3) < 1 or not len(cand):
        return None
    cand = cand[np.argsort(-size[cand], kind="stable")]
    take = min(len(cand), int(room), int(triangle_room / 3))   # a split adds >= 1.5 vertices, 3 triangles
    while take > 0:
        red = np.zeros(len(triangles), bool)
        red[cand[:take]] = True
        tri, edges = split_triangles(triangles, red, num_vertices)
        over = max(len(edges) / room, (len(tri) - len(triangles)) / triangle_room)
        if over <= 1:
            return tri, edges
        take = min(take - 1, int(take / over * 0.95))   # the closure split more than allowed: fewer
    return None


def colour_detail(positions, triangles, colors, cameras, images, fit, draw, budget, max_triangles):
    """The validated subdivision (module docstring). ``positions`` [N, 3] (the frame the
    ``cameras`` use), ``colors`` [N, 3] the colours to start from; ``fit(positions, triangles,
    prior, views)`` fits colours to the training views numbered ``views``; ``draw(positions,
    triangles, colors, view)`` is view ``view`` drawn as ``[H, W, 3]``; ``budget`` the most
    vertices, ``max_triangles`` the most triangles. Returns ``(triangles, steps, info)``: ``steps`` the kept levels' ``edges`` (as
    :func:`split_triangles` returns them), to apply in order with :func:`with_midpoints` to
    every per-vertex array (empty: the mesh as trained was kept); ``info`` a dict with each
    level's size threshold, vertex and triangle counts and validation PSNR, and the chosen
    level (0: none)."""
    tri = np.asarray(triangles, np.int64).reshape(-1, 3)
    views = list(range(len(cameras)))
    held = views[VALIDATION_EVERY // 2::VALIDATION_EVERY]
    info = dict(levels=[], chosen=0, held_back=len(held))
    if len(held) < MIN_VALIDATION_VIEWS or not len(tri):
        info["skipped"] = f"{len(views)} training views: fewer than {MIN_VALIDATION_VIEWS} to hold back"
        return tri, [], info
    if budget - len(positions) < MIN_ROOM * len(positions):
        info["skipped"] = (f"{len(positions):,} vertices: the detail budget of {budget:,} leaves no room for "
                           f"{100 * MIN_ROOM:.0f} percent more")
        return tri, [], info
    fitted = [v for v in views if v not in held]

    def validate(pos, t, col):
        c = fit(pos, t, col, fitted)
        return np.array([np.mean((np.asarray(draw(pos, t, c, v), np.float64) - images[v]) ** 2) for v in held])

    def level(px, err):
        return dict(px=px, vertices=len(pos), triangles=len(tri), psnr=_psnr(np.mean(err)),
                    view_psnr=[round(_psnr(e), 4) for e in err])

    pos, col = np.asarray(positions, np.float64), np.asarray(colors, np.float64)
    steps, best = [], (validate(pos, tri, col), tri, 0, 0)     # (per-view mse, triangles, steps, level)
    info["levels"].append(level(None, best[0]))
    for px in LEVEL_PX:
        step = refine_level(len(pos), tri, pixel_size(pos, tri, cameras), px, budget - len(pos),
                            max_triangles - len(tri))
        if step is None:
            continue
        tri, edges = step
        pos, col = with_midpoints(pos, edges), with_midpoints(col, edges)
        steps.append(edges)
        err = validate(pos, tri, col)
        info["levels"].append(level(px, err))
        if better(best[0], err):
            best = (err, tri, len(steps), len(info["levels"]) - 1)
    _, tri, n_steps, info["chosen"] = best
    return tri, steps[:n_steps], info


def better(best, new):
    """Whether a level whose held-back views have the per-view squared errors ``new`` beats the
    best so far (``best``): a lower mean error, and per-view gains (dB) whose mean is at least
    :data:`SIGNIFICANCE` standard errors above zero (one view's luck does not decide)."""
    best, new = np.asarray(best, np.float64), np.asarray(new, np.float64)
    if not np.mean(new) < np.mean(best):
        return False
    if SIGNIFICANCE <= 0 or len(new) < 2:
        return True
    gain = 10.0 * np.log10(np.maximum(best, 1e-20) / np.maximum(new, 1e-20))
    spread = float(np.std(gain, ddof=1)) / np.sqrt(len(gain))
    return float(np.mean(gain)) >= SIGNIFICANCE * spread


def _psnr(mse):
    return float(-10.0 * np.log10(max(mse, 1e-20)))
