"""The end of training: the exported mesh (:func:`final_mesh`).

method.md's cleanup renders every training view with the trained model and deletes the
triangles whose max blending weight is <= 0.5 (``config.final_prune``, off by default: those
triangles are the hidden layers other viewpoints see; never the shell's triangles beyond every
training view's image, the backdrop of other viewpoints), then the unused vertices; sigma and
opacity are dropped. Holes a training view still shows are filled with a fresh background
shell's triangles (``config.fill_holes``, :func:`backdrop_fill`), and so, just beyond the
trained shell, is what that shell lost behind the surfaces (``config.fill_hidden``); shards, large triangles that
draw the training views badly, and the floaters on the training cameras' path
(:func:`~.floaters.path_floaters`) are removed and the fill and the colours made again
(``config.remove_shards``, :func:`find_shards`), with the surface triangles in front of what the
photos show far away (``config.remove_far``, :mod:`.far_field`), less those the training views
draw worse without (``config.shard_check``, :func:`worse_without`); the mesh is subdivided where the held-back
training views say finer colours draw them better (``config.color_detail``, :mod:`.detail`). The vertex colours are
either the SH DC term (``config.mesh_colors = 'dc'``) or fitted to the training photos through
the exported, depth-tested mesh (``'fit'``, :func:`~tsplus_wgpu.render.mesh_fit.fit_vertex_colors`):
an engine draws one colour per vertex, and the SH DC term is the colour's mean over the whole
sphere rather than over the directions the photos saw.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..kernels.loss import supersampled_camera
from ..io.export import dc_colors
from .schedules import FINAL_PRUNE_WEIGHT
from .far_field import far_occluders
from .floaters import path_floaters
from .detail import LEVEL_PX, VALIDATION_SUPERSAMPLE, angular_size, colour_detail, with_midpoints
from .shell import SHELL, SURFACE, background_shell, beyond_views, shell_radius
from .sky import sky_triangles
from .strategy.cap import vertex_cap

#: samples per pixel side of the colour fit (reduced for large images, mesh_fit.MAX_SAMPLES)
FIT_SUPERSAMPLE = 2
#: a shard's angular size from the nearest training camera at least (rad; longest edge / distance)
SHARD_ANGLE = 0.15
#: and its pixels' mean squared error at least this many times the mean over all drawn pixels
SHARD_RESIDUAL = 2.0
#: with ``fill_hidden``, the fill's shell lies this fraction beyond the trained shell's radius
#: (whose vertices moved by at most 2 % on lund's default run), so the trained shell hides it
FILL_BEHIND = 0.05


class FinishProgress:
    """The end of training's progress on a tqdm-like ``bar`` (None: silent), in views drawn:
    every stage draws each training view once or twice (the detail's levels hold back a
    quarter of them for validation, drawn instead), so a view is about the same work in every
    stage. The total is planned at the start (:meth:`plan`) and corrected where a stage turns
    out to draw less (no shards found, fewer detail levels tried)."""

    def __init__(self, bar=None):
        self.bar = bar

    def plan(self, total):
        if self.bar is not None:
            self.bar.reset(total=max(int(total), 1))

    def stage(self, name):
        if self.bar is not None:
            self.bar.set_description(f"export: {name}")

    def tick(self, n=1):
        if self.bar is not None:
            self.bar.update(n)

    @property
    def done(self):
        return 0 if self.bar is None else int(self.bar.n)

    def replan(self, change):
        """The stage just ended drew ``change`` views more than planned (negative: fewer)."""
        if self.bar is not None and change:
            self.bar.total = max(self.bar.n, self.bar.total + int(change))
            self.bar.refresh()


def _progress(t):
    return getattr(t, "finish_progress", None) or FinishProgress()


def _planned(t):
    """``(total, export, detail)``: the views the end of training will draw as planned, and what
    one export (:func:`_exported`: its backdrop fill and colour fit) and the colour detail (every
    level validated, the kept one fitted) draw of them."""
    cfg, v = t.config, len(t.train_views)
    fit = cfg.mesh_colors == "fit"
    export = v * (int(bool(cfg.fill_holes)) + int(fit))
    detail = v * (len(LEVEL_PX) + 2) if cfg.color_detail and fit else 0
    total = (v if cfg.final_prune else 0) + export + detail + v     # the cleanup, an export, the detail, the winding
    if cfg.remove_shards:
        # the shards' pass (the far field's, the sky's), the export again
        total += v + export + (v if cfg.remove_far else 0) + (v if _sky_on(cfg) else 0)
        total += v if cfg.shard_check else 0                       # the check of what was removed
    return total, export, detail


def final_mesh(trainer, progress=None):
    """``(positions [V, 3] in world units, triangles [F, 3], colors [V, 3] in [0, 1])`` of
    ``trainer``'s model (module docstring). ``progress``: a tqdm-like bar that counts the views
    drawn (:class:`FinishProgress`)."""
    t, cfg = trainer, trainer.config
    t.finish_progress = bar = FinishProgress(progress)
    try:
        total, export, detail = _planned(t)
        bar.plan(total)
        keep = cleanup_mask(t)
        t.final_info = dict(filled_triangles=0, color_fit=None, shards=0, floaters=0, far=0, sky=0, shards_kept=0,
                            shards_checked=0)
        mesh = _exported(t, keep)
        if cfg.remove_shards and len(mesh[2]):
            mesh = _without_shards(t, keep, mesh, export)
        elif cfg.remove_shards:
            bar.replan(-(len(t.train_views) * (1 + int(cfg.remove_far) + int(_sky_on(cfg)) + int(cfg.shard_check))
                         + export))
        pos_frame, pos_world, tris, colors, _ = mesh
        if cfg.color_detail and cfg.mesh_colors == "fit":
            start = bar.done
            if len(tris):
                pos_frame, pos_world, tris, colors = detailed(t, pos_frame, pos_world, tris, colors)
            bar.replan(bar.done - start - detail)
        bar.stage("winding")
        tris, t.final_info["facing"] = facing_views(t, pos_frame, tris)
        return pos_world, tris, colors
    finally:
        t.finish_progress = None


def _without_shards(t, keep, mesh, export):
    """The exported mesh less the shards, the path's floaters and (``config.remove_far``) what
    stands in front of the far field; with ``config.shard_check``, the shards (by size and error
    alone: the floaters and the far field's have evidence of their own, the cameras' path and the
    neighbouring photos) whose pixels the training views draw worse without them are put back
    (:func:`worse_without`)."""
    cfg, bar = t.config, _progress(t)
    floaters = keep & path_floaters(t.positions_frame(), t.triangles_host, t.groups,
                                    [t.scene.cameras[v] for v in t.train_views])
    drawn = [] if cfg.shard_check else None
    sized = find_shards(t, *mesh, record=drawn)
    shards = sized | floaters
    in_far = find_far_occluders(t, mesh[0], mesh[2], mesh[4]) if cfg.remove_far else np.zeros(t.m, bool)
    far = ~shards & in_far
    shards |= far
    in_sky = find_sky(t, mesh[0], mesh[2], mesh[4]) if _sky_on(cfg) else np.zeros(t.m, bool)
    sky = ~shards & in_sky
    shards |= sky
    # the far field's and the sky's triangles are never checked, also those the size rule named:
    # the training views were fitted with them, so they draw worse without them (docs/measurements.md)
    out, back, checked = mesh, np.zeros(t.m, bool), sized & ~floaters & ~in_far & ~in_sky
    if shards.any():
        out = _exported(t, keep & ~shards)
    else:
        bar.replan(-export)
    if cfg.shard_check and checked.any():
        back = worse_without(t, mesh, out, drawn, checked)
        bar.replan(export if back.any() else 0)
        if back.any():
            shards &= ~back
            out = _exported(t, keep & ~shards)
    elif cfg.shard_check:
        bar.replan(-len(t.train_views))                            # nothing to check
    t.final_info.update(shards=int(shards.sum()), floaters=int((floaters & shards).sum()),
                        far=int((far & shards).sum()), sky=int((sky & shards).sum()), shards_kept=int(back.sum()),
                        shards_checked=int(checked.sum()))
    return out


def worse_without(t, mesh, out, drawn, removed):
    """``[M]`` bool over the trainer's triangles: those of ``removed`` whose pixels in the
    training views (``drawn``: per view, the exported triangle of each pixel of ``mesh`` and its
    squared error, from :func:`find_shards`) have a larger summed error in ``out`` (the mesh
    exported without every one of ``removed``, its fill and colours made again) than with it.
    A shard across free space draws every view badly, and what lies behind it draws them better;
    a near surface the photos show in detail draws them imperfectly too, but better than whatever
    is behind it."""
    pos_frame, _, tris, _, source = mesh
    cand = (source >= 0) & removed[np.maximum(source, 0)]
    with_, without = np.zeros(len(tris)), np.zeros(len(tris))
    gpu_mesh = t.mesh_renderer.upload((out[0], out[2], out[3]))
    _progress(t).stage("shard check")
    for v, (ids, r) in zip(t.train_views, drawn):
        img = t.mesh_renderer.render(gpu_mesh, t.scene.cameras[v], near=t.config.near).image
        _progress(t).tick()
        r2 = _view_error(t, img, v).astype(np.float32)      # as find_shards records r
        sel = ids >= 0
        sel[sel] = cand[ids[sel]]
        with_ += np.bincount(ids[sel], weights=r[sel], minlength=len(tris))
        without += np.bincount(ids[sel], weights=r2[sel], minlength=len(tris))
    worse = cand & (without > with_)
    back = np.zeros(t.m, bool)
    back[source[worse]] = True
    return back


def _view_error(t, img, v):
    """``[H, W]`` float64: the squared error of ``img`` against training view ``v``'s photo,
    the mean over the colour channels."""
    return np.mean((np.asarray(img, np.float64) - t.scene.images[v]) ** 2, axis=-1)


def _nearest(points, centers):
    """``[P]``: the index of the nearest of ``centers`` to each of ``points`` (the first on a tie),
    a camera at a time: no [P, C, 3] array (a paper-scale mesh's unseen triangles by 56 cameras
    made one of hundreds of megabytes)."""
    best, out = np.full(len(points), np.inf), np.zeros(len(points), np.int64)
    for k, c in enumerate(centers):
        d = ((points - c) ** 2).sum(-1)
        closer = d < best
        best[closer], out[closer] = d[closer], k
    return out


def facing_views(trainer, pos_frame, tris):
    """``(triangles, info)``: each triangle's winding turned so that its front (counter-clockwise
    corners, the right-hand normal) faces the training views that draw it, by pixels drawn from
    the front against from behind (the id pass, as the shards'); a triangle no view draws faces
    its nearest training camera. The trained triangles' winding is arbitrary (a Delaunay
    tetrahedralisation's faces), so an engine or format that culls back faces (an OBJ, a
    single-sided material) dropped about half of them. ``info``: the share of drawn pixels seen
    from the front before and after, and how many triangles were turned."""
    from ..render.mesh_fit import id_mesh, triangle_ids
    t = trainer
    tris = np.asarray(tris, np.int64)
    if not len(tris):
        return tris, None
    p = np.asarray(pos_frame, np.float64)
    a, b, c = p[tris[:, 0]], p[tris[:, 1]], p[tris[:, 2]]
    normal, centre = np.cross(b - a, c - a), (a + b + c) / 3.0
    cams = [t.scene.cameras[v] for v in t.train_views]
    front, back = np.zeros(len(tris)), np.zeros(len(tris))
    ids_mesh = id_mesh(t.mesh_renderer, p, tris)
    for cam in cams:
        ids = triangle_ids(t.mesh_renderer, p, tris, cam, t.config.near, ids_mesh)
        _progress(t).tick()
        seen = ids[ids >= 0]
        side = np.einsum("ij,ij->i", normal[seen], cam.center - centre[seen])
        front += np.bincount(seen, weights=side > 0, minlength=len(tris))
        back += np.bincount(seen, weights=side < 0, minlength=len(tris))
    drawn = float((front + back).sum())
    vote = front - back
    unseen = vote == 0
    if unseen.any():                                   # no view draws it (or as often from each side)
        centers = np.array([cam.center for cam in cams])
        near = _nearest(centre[unseen], centers)
        vote[unseen] = np.sign(np.einsum("ij,ij->i", normal[unseen], centers[near] - centre[unseen]))
    turn = vote < 0
    out = tris.copy()
    out[turn] = out[turn][:, [0, 2, 1]]
    share = (lambda x: round(float(x) / drawn, 4) if drawn else 1.0)  # noqa: E731
    return out, dict(front_before=share(front.sum()), front_after=share(np.maximum(front, back).sum()),
                     turned=int(turn.sum()), triangles=len(tris))


def cleanup_mask(trainer):
    """``[M]`` bool: the triangles method.md's cleanup keeps (all with ``final_prune`` off), and
    always the shell's beyond every training view's image."""
    t, cfg = trainer, trainer.config
    sigma = t.sched.sigma(t.iteration)
    ss = t.sched.supersample(t.iteration)     # as the last training steps rendered
    mw = np.full(t.m, np.inf if not cfg.final_prune else 0.0, np.float32)  # off: all kept
    if cfg.final_prune:
        _progress(t).stage("cleanup")
    for v in t.train_views if cfg.final_prune else ():
        cam = t.scene.cameras[v]
        res = t.renderer.forward(t.model, supersampled_camera(cam, t.fit_supersample(cam, ss)), sigma,
                                 cfg.background, cfg.near)
        mw = np.maximum(mw, res.max_weight)
        _progress(t).tick()
    return (mw > FINAL_PRUNE_WEIGHT) | beyond_views(t.groups, t.positions_frame(), t.triangles_host, [
        t.scene.cameras[v] for v in t.train_views], t.config.near)   # the backdrop of other viewpoints


def _exported(t, keep):
    """The kept triangles with their vertices, the backdrop fill and the colours:
    ``(positions in the frame, in world units, triangles, colours, source [F]: the trainer's
    triangle each came from, -1 for the fill)``."""
    cfg = t.config
    model = t.current_model()
    source = np.flatnonzero(keep)
    tris = model.triangles[keep]
    used = np.zeros(model.num_vertices, bool)
    used[tris.ravel()] = True
    tris = (np.cumsum(used) - 1)[tris]
    colors = dc_colors(model)[used]
    pos_frame, pos_world = t.positions_frame()[used].astype(np.float64), model.positions[used]
    if cfg.fill_holes:
        shell = None if t.groups is None or not cfg.fill_hidden else np.asarray(t.groups) == SHELL
        occluders = shell[source] if shell is not None and shell.any() else None   # (--shell off: holes only)
        add_pos, add_tri, add_col = backdrop_fill(t, pos_frame, tris, occluders)
        if len(add_tri):
            tris = np.concatenate([tris, add_tri + len(pos_frame)])
            pos_frame = np.concatenate([pos_frame, add_pos])
            pos_world = np.concatenate([pos_world, t.frame.to_world(add_pos)])
            colors = np.concatenate([colors, add_col])
            source = np.concatenate([source, np.full(len(add_tri), -1)])
        t.final_info["filled_triangles"] = int(len(add_tri))
    if cfg.mesh_colors == "fit" and len(tris):
        colors = fitted_colors(t, pos_frame, tris, colors)
    return pos_frame, pos_world, tris, colors, source


def find_shards(trainer, pos_frame, pos_world, tris, colors, source, record=None):
    """``[M]`` bool over the trainer's triangles: the shards of the exported mesh. A shard is a
    surface triangle that looks large from the training cameras (longest edge over the distance
    to the nearest training camera above :data:`SHARD_ANGLE` rad) and draws the training views
    badly (its pixels' mean squared error, with the exported colours, above
    :data:`SHARD_RESIDUAL` times the mean over every drawn pixel): a flat triangle across free
    space shows different scene content in every view, so no colour fits it. Removing them lets
    the backdrop fill and the colour fit take their pixels. ``record``: a list that gets, per
    training view, ``(ids, squared error)`` per pixel (:func:`worse_without`)."""
    from ..render.mesh_fit import id_mesh, triangle_ids
    t = trainer
    near = t.config.near
    err, count, total, drawn = np.zeros(len(tris)), np.zeros(len(tris)), 0.0, 0
    ids_mesh, mesh = id_mesh(t.mesh_renderer, pos_frame, tris), t.mesh_renderer.upload((pos_frame, tris, colors))
    _progress(t).stage("shards")
    for v in t.train_views:
        cam = t.scene.cameras[v]
        ids = triangle_ids(t.mesh_renderer, pos_frame, tris, cam, near, ids_mesh)
        img = t.mesh_renderer.render(mesh, cam, near=near).image
        _progress(t).tick()
        r = _view_error(t, img, v)
        ok = ids >= 0
        if record is not None:
            record.append((ids.astype(np.int32), r.astype(np.float32)))
        err += np.bincount(ids[ok], weights=r[ok], minlength=len(tris))
        count += np.bincount(ids[ok], minlength=len(tris))
        total, drawn = total + float(r[ok].sum()), drawn + int(ok.sum())
    mean_err = np.where(count > 0, err / np.maximum(count, 1), 0.0)
    edge, dist = angular_size(pos_frame, tris, [t.scene.cameras[v] for v in t.train_views])
    bad = _surface(t, source) & (edge > SHARD_ANGLE * dist) & (mean_err > SHARD_RESIDUAL * total / max(drawn, 1))
    out = np.zeros(t.m, bool)
    out[source[bad]] = True
    return out


def find_far_occluders(trainer, pos_frame, tris, source):
    """``[M]`` bool over the trainer's triangles: the surface triangles of the exported mesh
    ``(pos_frame, tris)`` (``source``: the trainer's triangle each came from, -1 for the fill) in
    front of what the training photos show far away (:mod:`.far_field`)."""
    t = trainer
    _progress(t).stage("far field")
    views = list(t.train_views)
    front = far_occluders(t.mesh_renderer, pos_frame, tris, [t.scene.cameras[v] for v in views],
                          [t.scene.images[v] for v in views], t.config.near, tick=_progress(t).tick)
    out = np.zeros(t.m, bool)
    out[source[front & _surface(t, source)]] = True
    return out


def _sky_on(cfg):
    """Whether the end of training looks for triangles in front of the sky: ``remove_sky``, and
    not in a scene declared indoor (``--indoor``), which has none."""
    return bool(cfg.remove_sky) and not bool(cfg.indoor)


def find_sky(trainer, pos_frame, tris, source):
    """``[M]`` bool over the trainer's triangles: the surface triangles of the exported mesh
    ``(pos_frame, tris)`` (``source``: the trainer's triangle each came from, -1 for the fill) whose
    pixels in the training photos are mostly sky (:mod:`.sky`)."""
    from ..data.upright import scene_upright
    t = trainer
    _progress(t).stage("sky")
    views = list(t.train_views)
    cams = [t.scene.cameras[v] for v in views]
    upright = scene_upright(t.scene)       # the photos' EXIF orientation where they have one
    found = sky_triangles(t.mesh_renderer, pos_frame, tris, cams, [t.scene.images[v] for v in views], t.config.near,
                          up=None if upright is None else upright.up, tick=_progress(t).tick)
    out = np.zeros(t.m, bool)
    out[source[found & _surface(t, source)]] = True
    return out


def _surface(t, source):
    """``[F]`` bool: the exported triangles (``source``: the trainer's triangle each came from, -1
    for the fill) that are the trainer's surface triangles."""
    groups = t.groups if t.groups is not None else np.zeros(t.m, np.int8)
    return (source >= 0) & (groups[np.maximum(source, 0)] == SURFACE)


def backdrop_fill(trainer, positions, triangles, occluders=None):
    """``(positions [K, 3] (frame), triangles [F, 3] into them, colours [K, 3])``: the triangles
    of a fresh background shell (:func:`~.shell.background_shell` of the training views) that
    some training view shows through a hole of the mesh ``(positions, triangles)``, i.e. where
    the depth-tested mesh draws nothing in front of them. Whatever the training left uncovered
    in a training view (SfM found no points there, its triangles were pruned or moved away) is
    drawn by the backdrop instead of the background colour; the colour fit then colours it.

    ``occluders`` (``[F]`` bool, ``config.fill_hidden``): only these triangles (the trained
    shell's) hide the fresh shell, which lies :data:`FILL_BEHIND` beyond it. The fill then also
    covers where the trained shell was deleted as hidden behind the surfaces in every training
    view: what a viewpoint between or beside them sees past a surface's edge. No photo shows
    those triangles, so they keep the fresh shell's colours (the photos' mean where they
    project)."""
    from ..render.mesh_fit import id_mesh, triangle_ids
    t = trainer
    cams = [t.scene.cameras[v] for v in t.train_views]
    radius = None if occluders is None else (1.0 + FILL_BEHIND) * shell_radius(t.scene.points)
    shell = background_shell(cams, [t.scene.images[v] for v in t.train_views], t.scene.points, radius=radius)
    empty = np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros((0, 3))
    if shell is None:
        return empty
    triangles = np.asarray(triangles, np.int64).reshape(-1, 3)
    if occluders is not None:
        triangles = triangles[np.asarray(occluders, bool)]
    m0 = len(triangles)
    allpos = np.concatenate([positions, shell.positions])
    alltri = np.concatenate([triangles, shell.triangles + len(positions)])
    seen = np.zeros(len(shell.triangles), bool)
    ids_mesh = id_mesh(t.mesh_renderer, allpos, alltri)
    _progress(t).stage("backdrop fill")
    for cam in cams:
        ids = triangle_ids(t.mesh_renderer, allpos, alltri, cam, t.config.near, ids_mesh)
        seen[ids[ids >= m0] - m0] = True
        _progress(t).tick()
    if not seen.any():
        return empty
    if occluders is not None:      # and their neighbours: a hole's edge is seen from other places too
        near_seen = np.zeros(shell.num_vertices, bool)
        near_seen[shell.triangles[seen].ravel()] = True
        seen |= near_seen[shell.triangles].any(axis=1)
    tri = shell.triangles[seen]
    used = np.zeros(shell.num_vertices, bool)
    used[tri.ravel()] = True
    return shell.positions[used], (np.cumsum(used) - 1)[tri], dc_colors(shell)[used]


def fitted_colors(trainer, positions, triangles, prior):
    """The least-squares vertex colours of the mesh ``(positions, triangles)`` (in the
    trainer's frame) against the training photos, drawn as ``tsplus eval`` draws it."""
    _progress(trainer).stage("colour fit")
    colors, info = fit_to_views(trainer, positions, triangles, prior, trainer.train_views)
    trainer.final_info["color_fit"] = info
    return colors


def fit_to_views(trainer, positions, triangles, prior, views):
    """``(colours, info)``: :func:`~tsplus_wgpu.render.mesh_fit.fit_vertex_colors` of the mesh
    against the scene's views numbered ``views``."""
    from ..render.mesh_fit import fit_vertex_colors
    t = trainer
    bar = _progress(t)
    return fit_vertex_colors(positions, triangles, [t.scene.cameras[v] for v in views],
                             [t.scene.images[v] for v in views], prior, t.config.near, t.mesh_renderer,
                             supersample=FIT_SUPERSAMPLE, background=t.config.background,
                             progress=lambda _k: bar.tick())


def detail_cap(config, cameras):
    """The most vertices the colour detail may bring the exported mesh to: ``config.detail_budget``
    x the training pixels (the training cap, ``vertex_budget``, when 0 or smaller), under
    ``max_vertices``; never the device's bound (the trainer never draws the export)."""
    budget = float(config.vertex_budget)
    if budget > 0 and config.detail_budget > budget:     # (no training budget: --max-vertices bounds both)
        budget = float(config.detail_budget)
    return vertex_cap(replace(config, vertex_budget=budget), cameras).vertices


def detailed(trainer, pos_frame, pos_world, triangles, colors):
    """``(positions in the frame, in world units, triangles, colours)``: the mesh subdivided as
    :func:`~.detail.colour_detail` chooses, within :func:`detail_cap` (without the device's
    bound: the trainer never draws it), and its colours fitted again to every training view."""
    from ..render.mesh_fit import ID_BASE
    t = trainer
    _progress(t).stage("colour detail")
    views = list(t.train_views)
    cams = [t.scene.cameras[v] for v in views]
    imgs = [t.scene.images[v] for v in views]
    near, bg = t.config.near, tuple(t.config.background)

    def fit(pos, tri, prior, which):
        return fit_to_views(t, pos, tri, prior, [views[i] for i in which])[0]

    def draw(pos, tri, col, i):
        img = t.mesh_renderer.render((pos, tri, col), cams[i], near=near, supersample=VALIDATION_SUPERSAMPLE,
                                     background=bg).image
        _progress(t).tick()
        return img

    budget = detail_cap(t.config, cams)
    tri, steps, info = colour_detail(pos_frame, triangles, colors, cams, imgs, fit, draw, budget,
                                     ID_BASE * ID_BASE - 1)
    t.final_info["detail"] = info
    if not steps:
        return pos_frame, pos_world, triangles, colors
    for edges in steps:
        pos_frame, pos_world = with_midpoints(pos_frame, edges), with_midpoints(pos_world, edges)
        colors = with_midpoints(colors, edges)
    return pos_frame, pos_world, tri, fitted_colors(t, pos_frame, tri, colors)
