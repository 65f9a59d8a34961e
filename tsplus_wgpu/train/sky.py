"""Surface triangles in front of the sky: found at the end of training.

SfM finds no point in a clear sky (nothing to match), so the initial Delaunay faces between
points on roofs, trees and the far end of a street span it, and training colours them like the
sky behind them. Seen from between the photos they stand at the wrong depth: their edges, and the
colours their shared vertices carry from the roofs, cut across the sky of a held-out view (lund's
skies were drawn as a mosaic of blue, grey and green shards). The far-field test
(:mod:`.far_field`) finds such triangles only where the sky has texture (clouds, roof edges):
where it is uniform both of its hypotheses match.

A photo shows its sky plainly. A pixel is sky (:func:`sky_mask`) when it is

* smooth: the gradient of the lightly blurred mean of the channels under :data:`SKY_GRADIENT` a
  pixel, measured on the photo area-resized to a long side of at most :data:`SKY_SIDE` pixels
  (so a 1,600 px photo's fine texture is not smooth for being spread over more pixels);
* blue: blue over red by :data:`SKY_BLUE`, not under green, and over :data:`SKY_MIN_BLUE`. A
  clear sky is the brightest blue in a photo, and few walls are blue; a dull blue-grey wall (the
  procedural room's, blue about 0.35) is not taken, nor are bright neutral pixels (an overcast
  sky, clouds): they are also white walls, ceilings and a synthetic scene's white background, and
  on lund they added 0.01 dB;
* above the horizon: its ray points up (the scene's up from its cameras,
  :func:`~tsplus_wgpu.data.upright.scene_upright`), so a blue car in the street is not sky;
* connected, through such pixels, to the image's upper border (the one the scene's up points
  to in that view: a photo stored sideways has it at a side): sky is what the view sees past
  everything above, so it reaches the frame there. (Any border, with bright pixels as sky too:
  lund's rule took in 84 more triangles, white walls at the sides, and gained 0.09 dB less.)

A view that looks within :data:`SKY_STEEP` of straight up or down has no sky pixels: which way
is up is least sure there (a nadir drone capture's up can come out reversed), and such a view
sees sky, if at all, without a horizon to tell it from a blue roof or a pool.

A surface triangle whose drawn pixels over the training views are at least :data:`SKY_SHARE`
sky pixels (and at least :data:`SKY_MIN_PIXELS` of them) stands in front of the sky
(:func:`sky_triangles`); the end of training removes it with the shards (``config.remove_sky``),
and the backdrop fill (the shell, far beyond every point) and the colour fit take its pixels, so
the sky is drawn where it is, far away. Only colours and directions enter, never lengths: the
rule does not depend on the world's units. What it cannot tell from the sky: a large smooth
blue surface above the horizon that reaches the frame (a blue wall or sofa back); the backdrop
drawn there takes the colour the training photos show in that direction.
"""

from __future__ import annotations

import numpy as np

#: the gradient of the channels' mean (per pixel, after a 3x3 Gaussian blur) a sky pixel stays under
SKY_GRADIENT = 0.06
#: the long side (pixels) a larger photo is area-resized to for the gradient
SKY_SIDE = 256
#: a clear sky's blue over its red at least, and blue at least
SKY_BLUE = 0.04
SKY_MIN_BLUE = 0.5
#: a view whose direction is within this angle (rad) of straight up or down has no sky pixels
SKY_STEEP = 0.5236
#: the share of a triangle's drawn pixels (over the training views) that are sky, at least
SKY_SHARE = 0.5
#: and at least this many of them
SKY_MIN_PIXELS = 2


def upper_border(camera, up):
    """Which border of ``camera``'s image the world direction ``up`` points to: ``'top'``,
    ``'bottom'``, ``'left'`` or ``'right'`` (``'top'`` without ``up``, or when it is along the
    view)."""
    if up is None:
        return "top"
    x, y, _ = np.asarray(camera.world_to_camera, np.float64)[:3, :3] @ np.asarray(up, np.float64)
    if abs(x) < 1e-9 and abs(y) < 1e-9:
        return "top"
    if abs(y) >= abs(x):
        return "top" if y < 0 else "bottom"             # image y points down
    return "left" if x < 0 else "right"


def sky_mask(image, camera=None, up=None):
    """``[H, W]`` bool: the sky pixels of ``image`` (``[H, W, 3]`` in [0, 1]; module docstring)
    seen by ``camera`` in a scene whose up is the world direction ``up``. Without them every
    pixel may be sky, and the upper border is the top row."""
    from scipy import ndimage
    from .far_field import pixel_rays
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[-1] != 3 or not np.issubdtype(img.dtype, np.floating):
        raise ValueError(f"image: expected float RGB [H, W, 3] in [0, 1], got {img.dtype} {img.shape}")
    img = img.astype(np.float32)
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    cand = _smooth(img) & (b > r + SKY_BLUE) & (b >= g) & (b > SKY_MIN_BLUE)
    if camera is not None and up is not None:
        up = np.asarray(up, np.float64)
        view = np.asarray(camera.world_to_camera, np.float64)[2, :3]          # the viewing direction
        if abs(float(view @ up)) > np.cos(SKY_STEEP) * np.linalg.norm(up):
            return np.zeros(img.shape[:2], bool)
        cand &= pixel_rays(camera) @ up > 0.0
    lab, n = ndimage.label(cand, structure=np.ones((3, 3)))
    if n == 0:
        return cand
    side = upper_border(camera, up) if camera is not None else "top"
    border = {"top": lab[0], "bottom": lab[-1], "left": lab[:, 0], "right": lab[:, -1]}[side]
    reach = np.zeros(n + 1, bool)
    reach[border] = True
    reach[0] = False
    return reach[lab]


def _smooth(img):
    """``[H, W]`` bool: the pixels whose blurred mean of the channels changes by under
    :data:`SKY_GRADIENT` a pixel, on the image area-resized to a long side of at most
    :data:`SKY_SIDE` (then back to the image's size, nearest)."""
    import cv2
    h, w = img.shape[:2]
    lum = np.ascontiguousarray(img.mean(-1))
    if max(h, w) > SKY_SIDE:
        s = SKY_SIDE / max(h, w)
        lum = cv2.resize(lum, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA)
    edge = cv2.BORDER_REPLICATE          # (a mirrored border would make the frame's own pixels smooth)
    lum = cv2.GaussianBlur(lum, (3, 3), 0, borderType=edge)
    gx = cv2.Sobel(lum, cv2.CV_32F, 1, 0, ksize=3, borderType=edge) / 8.0    # the kernel's weights sum to 8
    gy = cv2.Sobel(lum, cv2.CV_32F, 0, 1, ksize=3, borderType=edge) / 8.0
    smooth = (np.hypot(gx, gy) < SKY_GRADIENT).astype(np.uint8)
    if smooth.shape != (h, w):
        smooth = cv2.resize(smooth, (w, h), interpolation=cv2.INTER_NEAREST)
    return smooth.astype(bool)


def sky_triangles(mesh_renderer, positions, triangles, cameras, images, near, up=None, tick=None):
    """``[F]`` bool over ``triangles`` (of the mesh with ``positions``, drawn as ``tsplus eval``
    draws it): the triangles whose pixels in the views ``(cameras, images)`` are mostly sky
    (module docstring). ``up``: the scene's up (a world direction; None: not used). ``tick``:
    called after each view (not at all for an empty mesh)."""
    from ..render.mesh_fit import id_mesh, triangle_ids
    tris = np.asarray(triangles, np.int64).reshape(-1, 3)
    sky, drawn = np.zeros(len(tris)), np.zeros(len(tris))
    if not len(tris):
        return np.zeros(0, bool)
    uploaded = id_mesh(mesh_renderer, positions, tris)
    for cam, img in zip(cameras, images):
        ids = triangle_ids(mesh_renderer, positions, tris, cam, near, uploaded)
        mask = sky_mask(img, cam, up)
        ok = ids >= 0
        drawn += np.bincount(ids[ok], minlength=len(tris))
        sky += np.bincount(ids[ok & mask], minlength=len(tris))
        if tick is not None:
            tick()
    return (sky >= SKY_MIN_PIXELS) & (sky >= SKY_SHARE * drawn)
