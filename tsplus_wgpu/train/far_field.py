"""Surface triangles in front of what the photos show far away: found at the end of training.

An outdoor capture's sky is far beyond every surface SfM found, and a training view sees
it through the trained model only where no surface triangle lies in front of it. A forward
walk (lund) leaves triangles between the cameras and the sky that draw the sky's colour in
the views that trained them. Elsewhere they hide the house fronts and the trees behind them:
no photo says they are wrong, since every photo that sees them sees sky there.

The photos do say it, though, when they are compared in pairs. A pixel of a training view
that shows something at infinity shows the same thing in a neighbouring view along the same
*direction* (a rotation: no parallax), while a point at the exported mesh's depth there
moves by the parallax of that depth. So each drawn pixel of each training view is compared,
over a small window, with its :data:`FAR_NEIGHBOURS` nearest training views under both
hypotheses, where they fall at least :data:`FAR_PARALLAX` pixels apart. A neighbour votes
*far* when the direction's colour matches (mean absolute difference under
:data:`FAR_MATCH`) and beats the mesh depth's by :data:`FAR_MARGIN`, and *near* when the mesh
depth's beats it by that margin. A pixel with :data:`FAR_VOTES` far votes and more than
twice its near votes is far. Only pixels and colours enter, never lengths: the test does not
depend on the world's units.

A surface triangle is in front of the far field (:func:`far_occluders`) when it draws at
least :data:`FAR_VOTES` far pixels, more than twice its near ones and at least
:data:`FAR_SHARE` of all the pixels it draws. Uniform sky decides nothing (both hypotheses
match), so the votes come from where the sky meets clouds, roofs and trees. The end of
training removes these triangles with the shards (``config.remove_far``), and the backdrop
fill and the colour fit take their pixels (:mod:`.final`).
"""

from __future__ import annotations

import numpy as np

#: training views each pixel is compared with: the nearest by camera centre
FAR_NEIGHBOURS = 4
#: side of the square window (pixels) over which colour differences are averaged
FAR_WINDOW = 5
#: a neighbour votes when one hypothesis' mean absolute colour difference beats the other's by this much
FAR_MARGIN = 0.03
#: and a far vote also needs the direction's own difference under this (a match, not the lesser miss)
FAR_MATCH = 0.05
#: pixels in a neighbour between the two hypotheses' samples at least (else it cannot tell them apart)
FAR_PARALLAX = 2.0
#: far votes a pixel needs (and more than twice its near ones); far pixels a triangle needs likewise
FAR_VOTES = 2
#: and the far pixels' share of all the pixels the triangle draws at least
FAR_SHARE = 0.25


def pixel_rays(camera):
    """``[H, W, 3]``: each pixel centre's viewing direction in world space, scaled to camera z = 1."""
    u, v = np.meshgrid(np.arange(camera.width) + 0.5, np.arange(camera.height) + 0.5)
    x = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones_like(u)], -1)
    return x @ np.asarray(camera.world_to_camera, np.float64)[:3, :3]      # R^T x per pixel


def project(camera, points):
    """``(u, v, z)``: :meth:`~tsplus_wgpu.types.Camera.project` of world ``points`` ``[..., 3]``
    in their shape, u and v NaN at or behind the camera plane."""
    shape = points.shape[:-1]
    uv, z = camera.project(points.reshape(-1, 3))
    uv[z <= 0] = np.nan
    return uv[:, 0].reshape(shape), uv[:, 1].reshape(shape), z.reshape(shape)


def sample(image, u, v):
    """``(colours [..., 3], inside [...])``: ``image`` bilinearly at pixel coordinates ``(u, v)``;
    ``inside`` is False where a sample needs a pixel beyond the image (or u, v are NaN)."""
    import cv2
    h, w = image.shape[:2]
    x, y = u - 0.5, v - 0.5
    with np.errstate(invalid="ignore"):
        inside = (x >= 0) & (y >= 0) & (x <= w - 1) & (y <= h - 1)
    x = np.where(inside, x, -2.0).astype(np.float32)
    y = np.where(inside, y, -2.0).astype(np.float32)
    out = cv2.remap(np.asarray(image, np.float32), x, y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    return out, inside


def window_mean(values, valid, k=FAR_WINDOW):
    """``[H, W]``: the mean of ``values`` over the valid pixels of the k x k window around each
    pixel; NaN where under half the window is valid."""
    import cv2
    v = np.where(valid, values, 0.0).astype(np.float32)
    n = valid.astype(np.float32)
    total = cv2.boxFilter(v, -1, (k, k), normalize=False, borderType=cv2.BORDER_CONSTANT)
    count = cv2.boxFilter(n, -1, (k, k), normalize=False, borderType=cv2.BORDER_CONSTANT)
    return np.where(count >= 0.5 * k * k, total / np.maximum(count, 1.0), np.nan)


def far_pixels(camera, image, depth, neighbours, near):
    """``(far [H, W], near [H, W])`` bool: the pixels of the view ``(camera, image)`` whose
    neighbouring views (``neighbours``: ``(camera, image)`` pairs) say they show something at
    infinity, and those they say lie at ``depth`` (``[H, W]`` camera z of the mesh drawn there,
    0 where nothing is drawn), by the votes of the module docstring. ``near``: the near plane."""
    image = np.asarray(image, np.float32)
    depth = np.asarray(depth, np.float64)
    drawn = depth > 0
    rays = pixel_rays(camera)
    points = camera.center + depth[..., None] * rays
    far_votes = np.zeros(depth.shape, np.int32)
    near_votes = np.zeros(depth.shape, np.int32)
    for cam, img in neighbours:
        uf, vf, zf = project(cam, cam.center + rays)           # the direction alone: no parallax
        ud, vd, zd = project(cam, points)
        cf, okf = sample(img, uf, vf)
        cd, okd = sample(img, ud, vd)
        ef = window_mean(np.abs(cf - image).mean(-1), okf & (zf > 0))
        ed = window_mean(np.abs(cd - image).mean(-1), okd & (zd > near) & drawn)
        with np.errstate(invalid="ignore"):
            apart = np.hypot(uf - ud, vf - vd) > FAR_PARALLAX
            decides = drawn & apart & np.isfinite(ef) & np.isfinite(ed)
            far_votes += decides & (ef + FAR_MARGIN < ed) & (ef < FAR_MATCH)
            near_votes += decides & (ed + FAR_MARGIN < ef)
    far = (far_votes >= FAR_VOTES) & (far_votes > 2 * near_votes)
    near_px = (near_votes >= FAR_VOTES) & (near_votes > 2 * far_votes)
    return far, near_px


def nearest_views(centres, k=FAR_NEIGHBOURS):
    """``[C, min(k, C - 1)]``: for each camera centre the indices of the k nearest others (the
    lower index on a tie)."""
    c = np.asarray(centres, np.float64)
    d = np.linalg.norm(c[:, None] - c[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    return np.argsort(d, axis=1, kind="stable")[:, :max(0, min(k, len(c) - 1))]


def occluder_mask(far_count, near_count, drawn_count):
    """``[F]`` bool: the triangles in front of the far field by their pixel counts over the
    training views (module docstring)."""
    far_count, near_count = np.asarray(far_count), np.asarray(near_count)
    return ((far_count >= FAR_VOTES) & (far_count > 2 * near_count)
            & (far_count >= FAR_SHARE * np.asarray(drawn_count)))


def far_occluders(mesh_renderer, positions, triangles, cameras, images, near, tick=None):
    """``[F]`` bool over ``triangles`` (of the mesh with ``positions``, drawn as ``tsplus
    eval`` draws it): the triangles in front of what the views ``(cameras, images)`` show far
    away (module docstring). ``tick``: called after each view."""
    from ..render.mesh_fit import id_mesh, ids_and_depth
    tris = np.asarray(triangles, np.int64).reshape(-1, 3)
    counts = np.zeros((3, len(tris)))
    if not len(tris):
        return np.zeros(len(tris), bool)
    uploaded = id_mesh(mesh_renderer, positions, tris)
    others = nearest_views([c.center for c in cameras])
    for a, cam in enumerate(cameras):
        ids, depth = ids_and_depth(mesh_renderer, positions, tris, cam, near, uploaded)
        drawn = ids >= 0
        far, near_px = far_pixels(cam, images[a], depth, [(cameras[b], images[b]) for b in others[a]], near)
        for row, which in enumerate((far, near_px, drawn)):
            counts[row] += np.bincount(ids[drawn & which], minlength=len(tris))
        if tick is not None:
            tick()
    return occluder_mask(*counts)
