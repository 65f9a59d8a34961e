"""The :class:`Scene` that every loader returns, and the frame-loading pipeline they share."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Optional

import numpy as np

from ..types import Camera
from .errors import SceneError
from .frame import WorldFrame
from .images import composite, read_image_raw, resize_area
from .plausible import check_train_size, check_translation
from .upright import scene_upright


@dataclass
class GTMesh:
    """Ground-truth geometry of a synthetic scene.

    Attributes:
        vertices: ``[V, 3]`` float64 world positions.
        faces: ``[F, 3]`` int64 vertex indices.
        face_object: ``[F]`` int32 object id of each face (index into ``object_names``).
        object_names: name of each object id.
    """

    vertices: np.ndarray
    faces: np.ndarray
    face_object: np.ndarray
    object_names: list


@dataclass
class Scene:
    """Everything training needs from a capture.

    Attributes:
        format: ``"colmap"``, ``"transforms"`` (instant-ngp), ``"nerf-synthetic"``, ``"llff"``,
            ``"photos"`` (SfM run here), ``"video"`` (a video's frames, SfM run here) or ``"procedural"``.
        cameras: one pinhole :class:`Camera` per image (undistorted, at the loaded size).
        images: float32 ``[H, W, 3]`` RGB in [0, 1], alpha composited on ``background``.
        image_names: names relative to the image folder.
        points: ``[P, 3]`` float64 initial points, or None.
        point_colors: ``[P, 3]`` float in [0, 1], or None.
        point_tracks: which views observed each point (SfM tracks), or None when unknown: a track
            table ``(offsets int64 [P+1], views int32 [K])`` (:mod:`~tsplus_wgpu.data.tracks`);
            point p was seen by the cameras ``views[offsets[p]:offsets[p+1]]`` (indices into
            ``cameras``). SfM (COLMAP, photos), triangulated and procedural points have them;
            frusta points do not.
        points_source: ``"sfm"``, ``"triangulated"``, ``"frusta"``, ``"procedural"`` or ``"none"``.
        train_indices, test_indices: indices into ``cameras``/``images``.
        warnings: human-readable notes about what was skipped or replaced.
        root: the scene folder (None for the procedural scene).
        background: the RGB triple alpha was composited on.
        skipped: ``(image name, reason)`` for images that could not be used.
        camera_models: original camera model name -> number of images.
        split_rule: how the split was made, for the summary.
        image_dir: the folder the images were read from (None for the procedural scene).
        image_dir_reason: why that folder (e.g. ``images/`` is missing), for the summary.
        downscale: the total factor the images were shrunk by relative to the camera model's size.
        gt_mesh: ground-truth mesh (procedural scene only).
        masks: per view ``[H, W]`` int16 object ids, -1 where nothing (procedural scene only).
        depths: per view ``[H, W]`` float32 camera-space z of the surface (procedural scene only).
    """

    format: str
    cameras: list
    images: list
    image_names: list
    points: Optional[np.ndarray] = None
    point_colors: Optional[np.ndarray] = None
    point_tracks: Optional[tuple] = None
    points_source: str = "none"
    train_indices: list = field(default_factory=list)
    test_indices: list = field(default_factory=list)
    warnings: list = field(default_factory=list)
    root: Optional[str] = None
    background: tuple = (0.0, 0.0, 0.0)
    skipped: list = field(default_factory=list)
    camera_models: dict = field(default_factory=dict)
    split_rule: str = ""
    image_dir: Optional[str] = None
    image_dir_reason: str = ""
    downscale: float = 1.0
    gt_mesh: Optional[GTMesh] = None
    masks: Optional[list] = None
    depths: Optional[list] = None

    @property
    def num_images(self) -> int:
        return len(self.images)

    @property
    def train_cameras(self) -> list:
        return [self.cameras[i] for i in self.train_indices]

    @property
    def test_cameras(self) -> list:
        return [self.cameras[i] for i in self.test_indices]

    def scene_extent(self) -> float:
        """Radius of the camera centres around their mean (x 1.1), as 3DGS-style trainers use it."""
        if not self.cameras:
            return 1.0
        c = np.stack([cam.center for cam in self.cameras])
        r = float(np.max(np.linalg.norm(c - c.mean(0), axis=1))) if len(c) > 1 else 0.0
        return 1.1 * r if r > 0 else 1.0

    def frame(self) -> WorldFrame:
        """The normalised frame training works in (:class:`~.frame.WorldFrame`), from every
        camera, training and held-out, so that training and evaluation agree."""
        return WorldFrame.for_cameras(self.cameras, self.points)

    def in_frame(self, frame: WorldFrame) -> "Scene":
        """This scene seen in ``frame``: a shallow copy whose cameras, points, ground-truth mesh
        and depth maps are mapped into it (images, masks, point tracks and everything else shared)."""
        gt = self.gt_mesh
        return replace(self, cameras=[frame.camera(c) for c in self.cameras],
                       points=None if self.points is None else frame.to_frame(self.points),
                       gt_mesh=None if gt is None else replace(gt, vertices=frame.to_frame(gt.vertices)),
                       depths=None if self.depths is None else [np.float32(frame.scale) * d for d in self.depths])

    def summary(self) -> str:
        """Multi-line human-readable description (what ``tsplus inspect`` prints)."""
        lines = [f"scene:      {self.root if self.root else '(built-in procedural scene)'}",
                 f"format:     {self.format}"]
        models = ", ".join(f"{k} x{v}" for k, v in sorted(self.camera_models.items())) or "pinhole"
        intr = {(c.width, c.height, round(c.fx, 3), round(c.fy, 3), round(c.cx, 3), round(c.cy, 3))
                for c in self.cameras}
        lines.append(f"cameras:    {len(self.cameras)} ({len(intr)} distinct intrinsics; source model: {models})")
        if self.cameras:
            fx = np.array([c.fx for c in self.cameras])
            fov = np.degrees(2 * np.arctan(np.array([c.width / (2 * c.fx) for c in self.cameras])))
            lines.append(f"focal:      fx {fx.min():.2f}..{fx.max():.2f} px, horizontal FOV "
                         f"{fov.min():.1f}..{fov.max():.1f} deg")
            centers = np.stack([c.center for c in self.cameras])
            lo, hi = centers.min(0), centers.max(0)
            lines.append("centres:    box " + " .. ".join("(" + ", ".join(f"{x:.3g}" for x in v) + ")"
                                                          for v in (lo, hi)))
            up = scene_upright(self)
            lines.append(f"up:         ({', '.join(f'{x:.3f}' for x in up.up)}) from {up.how}; rms roll "
                         f"{up.rms_roll_deg:.1f} deg" + (f"; {up.sideways} photos stored sideways" if up.sideways
                                                         else "") + " (export --y-up stands the mesh on it)")
        if self.image_dir:
            lines.append(f"image dir:  {self.image_dir}" + (f" ({self.image_dir_reason})" if self.image_dir_reason else ""))
        sizes = Counter(f"{im.shape[1]}x{im.shape[0]}" for im in self.images)
        size_txt = ", ".join(f"{k} ({v})" for k, v in sizes.most_common()) or "none"
        lines.append(f"images:     {len(self.images)} loaded, sizes {size_txt}")
        if self.skipped:
            lines.append(f"skipped:    {len(self.skipped)} image(s): "
                         + "; ".join(f"{n} ({r})" for n, r in self.skipped[:5])
                         + (" ..." if len(self.skipped) > 5 else ""))
        if self.points is not None:
            lines.append(f"points:     {len(self.points)} ({self.points_source})")
        else:
            lines.append(f"points:     none ({self.points_source})")
        lines.append(f"split:      {len(self.train_indices)} train / {len(self.test_indices)} test"
                     + (f" ({self.split_rule})" if self.split_rule else ""))
        lines.append(f"background: ({', '.join(f'{v:g}' for v in self.background)})")
        if self.gt_mesh is not None:
            lines.append(f"gt mesh:    {len(self.gt_mesh.vertices)} vertices, {len(self.gt_mesh.faces)} faces, "
                         f"{len(self.gt_mesh.object_names)} objects ({', '.join(self.gt_mesh.object_names)})")
        if self.warnings:
            lines.append(f"warnings:   {len(self.warnings)}")
            lines.extend(f"  - {w}" for w in self.warnings)
        else:
            lines.append("warnings:   none")
        return "\n".join(lines)


@dataclass
class FrameSpec:
    """One image as a format loader describes it, before any pixel is read.

    Attributes:
        name: image name shown to the user (relative to the image folder).
        path: file to read.
        camera: pinhole part of the camera at ``model_size`` (distorted intrinsics if ``undistort``).
        group: intrinsics group (a COLMAP camera id, or "shared"): images of one group must share a size.
        undistort: optional ``(img, camera) -> (img, camera)``.
        is_test: True when the format itself marks this frame as held out (NeRF-synthetic test split).
        source: the file that describes this frame (for error messages).
        model: camera model name of the source (for the summary).
    """

    name: str
    path: Path
    camera: Camera
    group: object = "shared"
    undistort: Optional[Callable] = None
    is_test: bool = False
    source: str = ""
    model: str = "PINHOLE"


def check_pose(m, where: str) -> np.ndarray:
    """Validate a 4x4 world-to-camera matrix; raise SceneError naming ``where`` if not finite / not a rotation."""
    m = np.asarray(m, np.float64)
    if m.shape != (4, 4) or not np.all(np.isfinite(m)):
        raise SceneError(f"{where}: pose contains non-finite values (NaN or Inf); "
                         "fix or remove this image from the model")
    R = m[:3, :3]
    if abs(np.linalg.det(R) - 1.0) > 1e-3 or np.abs(R @ R.T - np.eye(3)).max() > 1e-3:
        raise SceneError(f"{where}: pose rotation is not orthonormal (det {np.linalg.det(R):.4g}); "
                         "fix or remove this image from the model")
    check_translation(m[:3, 3], where, "translation")
    check_translation(-R.T @ m[:3, 3], where, "camera centre")
    return m


def make_split(n: int, split, is_test: Optional[list] = None) -> tuple[list, list, str]:
    """Train / test indices over ``n`` frames.

    Args:
        n: number of frames (in the format's order).
        split: ``"auto"`` (the format's own test frames when it has them, else every 8th frame,
            index % 8 == 0, held out, as the paper's code does), ``"none"`` (train on all),
            ``"every8"`` / an integer k (every k-th frame held out).
        is_test: per-frame flags from the format (NeRF-synthetic).
    """
    if split is None or split == "auto":
        if is_test is not None and any(is_test):
            test = [i for i in range(n) if is_test[i]]
            return [i for i in range(n) if not is_test[i]], test, "the format's test split"
        k = 8
    elif split == "none":
        return list(range(n)), [], "none: all images train"
    elif isinstance(split, str) and split.startswith("every"):
        try:
            k = int(split[5:])
        except ValueError:
            raise SceneError(f"split {split!r}: expected 'auto', 'none' or 'everyK'") from None
    elif isinstance(split, (int, np.integer)) and not isinstance(split, bool):
        k = int(split)
    else:
        raise SceneError(f"split {split!r}: expected 'auto', 'none' or 'everyK'")
    if k < 2:
        raise SceneError(f"split {split!r}: the hold-out period must be >= 2")
    test = [i for i in range(n) if i % k == 0]
    return [i for i in range(n) if i % k != 0], test, f"every {k}th image held out (index % {k} == 0)"


def select_frames(frames: list, only) -> list:
    """Keep the frames named in ``only`` (indices into ``frames`` or image names), in ``frames`` order."""
    if only is None:
        return list(range(len(frames)))
    names = {f.name: i for i, f in enumerate(frames)}
    keep = set()
    for item in only:
        if isinstance(item, (int, np.integer)) and not isinstance(item, bool):
            if not 0 <= int(item) < len(frames):
                raise SceneError(f"frame index {item} out of range (the scene has {len(frames)} images)")
            keep.add(int(item))
        else:
            if str(item) not in names:
                raise SceneError(f"frame {item!r} is not an image of this scene")
            keep.add(names[str(item)])
    return sorted(keep)


def load_frames(frames: list, downscale: float, background, on_bad_image: str, warnings: list,
                progress: bool = False):
    """Read, check, undistort, composite and resize the images of ``frames``.

    Args:
        frames: :class:`FrameSpec` list.
        downscale: extra factor (>= 1) to shrink images by after undistortion.
        background: RGB in [0, 1] for alpha compositing.
        on_bad_image: ``"skip"`` (warn, skip, count in the summary) or ``"error"``.
        warnings: list to append warnings to.

    Returns:
        ``(cameras, images, kept, skipped)``: kept = indices into ``frames`` that loaded.
    """
    cameras, images, kept, skipped = [], [], [], []
    group_size: dict = {}
    it = enumerate(frames)
    if progress and len(frames) > 20:
        try:
            from tqdm import tqdm  # noqa: PLC0415
            it = tqdm(it, total=len(frames), desc="loading images", unit="img", leave=False)
        except ImportError:  # pragma: no cover
            pass
    for i, fr in it:
        try:
            raw = read_image_raw(fr.path)
        except SceneError as exc:
            if on_bad_image == "error":
                raise
            reason = "missing" if not Path(fr.path).is_file() else "unreadable"
            skipped.append((fr.name, reason))
            warnings.append(f"skipped {fr.path}: {str(exc).split(': ', 1)[-1]}")
            continue
        h, w = raw.shape[:2]
        g = fr.group
        if g in group_size and group_size[g][0] != (w, h):
            (gw, gh), first = group_size[g]
            raise SceneError(f"{fr.path}: image is {w}x{h} but {first} of the same camera is {gw}x{gh}; "
                             "give each image size its own camera or resize the images to one size")
        group_size.setdefault(g, ((w, h), fr.name))
        cam, img = prepare_frame(fr, raw, downscale, background)
        cameras.append(cam)
        images.append(img)
        kept.append(i)
    if not kept:
        first = frames[0].path if frames else "(no images)"
        raise SceneError(f"{first}: none of the {len(frames)} images could be read; check the image folder")
    if skipped:
        warnings.append(f"{len(skipped)} of {len(frames)} images skipped (missing or unreadable)")
    return cameras, images, kept, skipped


def downscaled_size(width: int, height: int, downscale: float) -> tuple:
    """``(width, height)`` of an image shrunk by ``downscale``: each side divided and rounded
    (at least 1 pixel). What ``--downscale`` gives, and what plans one (``tsplus train``)."""
    return max(1, int(round(width / downscale))), max(1, int(round(height / downscale)))


def prepare_frame(fr: FrameSpec, raw: np.ndarray, downscale: float, background):
    """The pinhole camera and float32 RGB image of frame ``fr`` from its decoded file ``raw``:
    intrinsics scaled to the file's size, undistorted, alpha composited, shrunk by ``downscale``."""
    h, w = raw.shape[:2]
    cam = fr.camera
    if (w, h) != (cam.width, cam.height):
        sx, sy = w / cam.width, h / cam.height
        if abs(sx - sy) > 0.02 * max(sx, sy) + 1.0 / min(w, h):
            raise SceneError(f"{fr.path}: image is {w}x{h} but {fr.source or 'its camera'} says "
                             f"{cam.width}x{cam.height} (different aspect ratio); use the images the "
                             "cameras were computed from")
        cam = Camera(w, h, cam.fx * sx, cam.fy * sy, cam.cx * sx, cam.cy * sy, cam.world_to_camera)
    img = raw
    if fr.undistort is not None:
        img, cam = fr.undistort(img, cam)
    img = composite(img, background)
    if downscale != 1:
        nw, nh = downscaled_size(cam.width, cam.height, downscale)
        check_train_size(nw, nh, (cam.width, cam.height), downscale, str(fr.path))
        img = resize_area(img, nw, nh)
        cam = cam.scaled(nw / cam.width) if (nw / cam.width) == (nh / cam.height) else Camera(
            nw, nh, cam.fx * nw / cam.width, cam.fy * nh / cam.height, cam.cx * nw / cam.width,
            cam.cy * nh / cam.height, cam.world_to_camera)
    return cam, np.clip(img, 0.0, 1.0).astype(np.float32, copy=False)


def full_size_frame(fr: FrameSpec, background):
    """``(camera, image)`` of ``fr`` at its file's size (undistorted, composited), or None when
    the file cannot be read: what triangulation reads, one image at a time."""
    try:
        raw = read_image_raw(fr.path)
    except SceneError:
        return None
    return prepare_frame(fr, raw, 1.0, background)
