"""Writing, reading and checking trainer checkpoints (``checkpoint.npz``).

A checkpoint is an ``.npz`` of the trainer's arrays in the device layout
(:meth:`~.trainer.Trainer.state_arrays`: ``positions``, ``sh_planar``, ``logits``, ``triangles``,
``exp_avg_<p>`` / ``exp_avg_sq_<p>``), the topology's ``max_weight_acc``, ``l1_ring`` and ``triangle_groups`` (int8 per triangle, the
background shell's marked; absent when every triangle is ordinary), and
``meta`` (JSON bytes: ``version``, ``iteration``, ``elapsed``, ``frame``, ``topology``,
``config``, ``adapter``). :func:`tsplus_wgpu.apps.runs.load_run` reads the same files.

Units (version 2): ``positions`` are in world units, float64 (the trainer's float32 frame
positions mapped by :meth:`~tsplus_wgpu.data.frame.WorldFrame.to_world`), so that what a user
reads from a checkpoint is the scene's geometry like ``mesh.ply``; ``meta["frame"]`` is the
:class:`~tsplus_wgpu.data.frame.WorldFrame` the run trains in. ``positions_frame`` keeps the
device's float32 frame positions as well, and a resume reads those: mapping float64 world values
back is exact only while the world's offset is below about 1e4 camera radii (near a UTM-sized
offset, float64 world values are too coarse to tell neighbouring float32 frame values apart), so
this keeps a resume bit-identical at any offset. The Adam moments are optimiser state and stay
as the device holds them, in frame units. A version-1 checkpoint (positions in the scene's
absolute units, no frame) is refused.

What identifies the training data (:func:`data_fingerprint`: the scene's absolute path, format,
downscale, image folder, image names and sizes, a digest of the pixels, the number of points) is
kept in the config's ``extra["data"]``, so ``--resume`` refuses other data
(:func:`check_fingerprint`).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, fields
from pathlib import Path

import numpy as np

from ..data.frame import WorldFrame
from ..errors import UserError
from ..io.atomic import atomic_write
from .config import TrainConfig

CHECKPOINT_VERSION = 2


class CheckpointError(UserError, ValueError):
    """A checkpoint that cannot be resumed: one line naming the file (and the array)."""


def _required_arrays():
    from .state import MOMENTS, PARAMS
    return ["positions", "sh_planar", "logits", "triangles"] + [f"{m}_{p}" for p in PARAMS for m in MOMENTS]


def _load_arrays(path):
    """Every array of the ``.npz`` at ``path``; a :class:`CheckpointError` naming the array
    that cannot be read."""
    try:
        z = np.load(path)
    except Exception as exc:
        raise CheckpointError(f"--resume: {path} is not a readable tsplus checkpoint ({exc}); start again "
                              f"without --resume in a new --out folder") from None
    arrays = {}
    with z:
        for k in z.files:
            try:
                arrays[k] = z[k]
            except Exception as exc:
                raise CheckpointError(f"--resume: {path}: array '{k}' is corrupt ({exc}); start again without "
                                      f"--resume in a new --out folder") from None
    return arrays


def _check_arrays(path, arrays):
    """Every array a resume needs is there, with consistent shapes and finite values."""
    missing = [k for k in _required_arrays() if k not in arrays]
    if missing:
        raise CheckpointError(f"--resume: {path} lacks the array{'s' if len(missing) > 1 else ''} "
                              f"{', '.join(repr(k) for k in missing)}; start again without --resume in a new "
                              f"--out folder")
    pos, sh = arrays["positions"], arrays["sh_planar"]
    n = pos.shape[0] if pos.ndim == 2 else -1
    shapes = dict(positions=(n, 3), sh_planar=(sh.shape[0] if sh.ndim == 3 else -1, n, 3), logits=(n,))
    k = shapes["sh_planar"][0]
    sizes = dict(positions=3 * n, sh=3 * n * k, logits=n)
    for key, size in sizes.items():
        for mom in ("exp_avg", "exp_avg_sq"):
            shapes[f"{mom}_{key}"] = (size,)
    for name, shape in shapes.items():
        a = arrays[name]
        if n < 0 or k < 1 or a.shape != shape or not np.issubdtype(a.dtype, np.floating):
            raise CheckpointError(f"--resume: {path}: array '{name}' has shape {a.shape} ({a.dtype}), expected "
                                  f"{shape} float; the checkpoint is corrupt")
        if not np.all(np.isfinite(a)):
            raise CheckpointError(f"--resume: {path}: array '{name}' holds NaN or infinite values; the checkpoint "
                                  f"is corrupt")
    t = arrays["triangles"]
    if t.ndim != 2 or t.shape[1] != 3 or not np.issubdtype(t.dtype, np.integer) or \
            (t.size and (t.min() < 0 or t.max() >= n)):
        raise CheckpointError(f"--resume: {path}: array 'triangles' is not [M, 3] vertex indices below {n}; the "
                              f"checkpoint is corrupt")
    mw = arrays.get("max_weight_acc")
    if mw is not None and (mw.shape != (t.shape[0],) or not np.all(np.isfinite(mw))):
        raise CheckpointError(f"--resume: {path}: array 'max_weight_acc' has shape {mw.shape} or non-finite values, "
                              f"expected ({t.shape[0]},) finite; the checkpoint is corrupt")
    pf = arrays.get("positions_frame")
    if pf is not None and (pf.shape != (n, 3) or pf.dtype != np.float32 or not np.all(np.isfinite(pf))):
        raise CheckpointError(f"--resume: {path}: array 'positions_frame' has shape {pf.shape} / dtype {pf.dtype} "
                              f"or non-finite values, expected ({n}, 3) float32; the checkpoint is corrupt")
    groups = arrays.get("triangle_groups")
    if groups is not None and (groups.shape != (t.shape[0],) or not np.issubdtype(groups.dtype, np.integer)):
        raise CheckpointError(f"--resume: {path}: array 'triangle_groups' has shape {groups.shape} or dtype "
                              f"{groups.dtype}, expected ({t.shape[0]},) integers; the checkpoint is corrupt")


def write_checkpoint(path, trainer):
    """Write ``trainer``'s checkpoint to ``path`` atomically (temp file + os.replace): its
    :meth:`~.trainer.Trainer.state_arrays` with the positions in world units, its
    :meth:`~.trainer.Trainer.topology_arrays` and ``meta`` (the frame among it)."""
    arrays = trainer.state_arrays()
    arrays["positions_frame"] = arrays["positions"]                          # [N, 3] float32, for resume
    arrays["positions"] = trainer.frame.to_world(arrays["positions"])      # [N, 3] float64
    arrays.update(trainer.topology_arrays())
    meta = dict(version=CHECKPOINT_VERSION, iteration=trainer.iteration, elapsed=trainer.elapsed,
                frame=trainer.frame.to_json(), topology=trainer.topology.state(),
                config=asdict(trainer.config), adapter=trainer.renderer.adapter_name,
                view_rng="numpy default_rng([seed, epoch]).permutation per epoch (stateless)")
    arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    atomic_write(path, lambda f: np.savez(f, **arrays))


def read_checkpoint(path):
    """``(arrays, meta)`` of the checkpoint at ``path`` (a ``--resume`` error naming the file,
    and the array, otherwise)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"--resume: no checkpoint at {path}")
    arrays = _load_arrays(path)
    if "meta" not in arrays:
        raise CheckpointError(f"--resume: {path} lacks the array 'meta'; it is not a tsplus checkpoint")
    try:
        meta = json.loads(bytes(arrays.pop("meta")).decode())
        if not isinstance(meta, dict) or not isinstance(meta.get("config"), dict):
            raise ValueError("no config in it")
        int(meta["iteration"])
    except Exception as exc:
        raise CheckpointError(f"--resume: {path}: array 'meta' is not a tsplus checkpoint's ({exc}); start "
                              f"again without --resume in a new --out folder") from None
    if meta.get("version") == 1:
        raise CheckpointError(f"--resume: {path} was written by an older tsplus (checkpoint version 1: positions in "
                              f"absolute scene units); train again in a new --out folder")
    if meta.get("version") != CHECKPOINT_VERSION:
        raise CheckpointError(f"--resume: {path} has checkpoint version {meta.get('version')}, "
                              f"this tsplus reads {CHECKPOINT_VERSION}")
    try:
        WorldFrame.from_json(meta.get("frame"))
    except (TypeError, ValueError) as exc:
        raise CheckpointError(f"--resume: {path}: array 'meta' has no valid 'frame' ({exc}); the checkpoint is "
                              f"corrupt") from None
    _check_arrays(path, arrays)
    return arrays, meta


def scene_id(scene_arg):
    """The scene argument as stored with a run: ``procedural:<size>``, or the absolute path."""
    if scene_arg is None or str(scene_arg).startswith("procedural"):
        s = str(scene_arg or "procedural")
        return s if ":" in s else "procedural:small"
    return str(Path(scene_arg).resolve())


def data_fingerprint(scene, scene_arg, downscale=1, images=None):
    """What identifies a scene's training data (JSON): ``scene`` (absolute path or
    ``procedural:<size>``), ``format``, ``downscale``, ``images`` (the image folder asked for),
    ``image_dir`` (the image folder read), ``views`` (the number of images), ``image_names`` / ``image_sizes`` / ``pixels``
    (SHA-256 digests, 16 hex digits: names, W x H of each, a strided sample of every image's
    pixels), ``train`` (the training views' digest: a photo the loader left out changes it) and
    ``points`` (the number of initial points)."""
    names = hashlib.sha256("\n".join(map(str, scene.image_names)).encode()).hexdigest()[:16]
    sizes = hashlib.sha256(";".join(f"{c.width}x{c.height}" for c in scene.cameras).encode()).hexdigest()[:16]
    pix = hashlib.sha256()
    for img in scene.images:
        img = np.asarray(img)
        step = max(1, int(np.sqrt(img.shape[0] * img.shape[1] / 4096)))    # about 4096 pixels per image
        pix.update(np.ascontiguousarray(img[::step, ::step], np.float32).tobytes())
    image_dir = getattr(scene, "image_dir", None)
    train = hashlib.sha256(",".join(map(str, getattr(scene, "train_indices", ()))).encode()).hexdigest()[:16]
    return dict(scene=scene_id(scene_arg), format=scene.format, downscale=downscale, images=images,
                image_dir=Path(image_dir).name if image_dir else None, views=len(scene.images), image_names=names, image_sizes=sizes, pixels=pix.hexdigest()[:16],
                train=train, points=0 if scene.points is None else int(len(scene.points)))


#: fingerprint key -> how a difference is named
_WHAT = dict(scene="scene", format="scene format", downscale="--downscale", images="--images",
             image_dir="image folder",
             views="number of images", image_names="image names", image_sizes="image sizes",
             pixels="image content", train="training views", points="number of initial points")


def check_fingerprint(path, saved, current, keys=None):
    """Refuse to continue the checkpoint at ``path`` whose data fingerprint is ``saved`` on data
    whose fingerprint is ``current`` (compare only ``keys`` when given: the cheap ones, before
    the scene is loaded). ``saved`` None (an older checkpoint): returns a warning line."""
    if not saved:
        return (f"{path} was written by an older tsplus and does not record its scene; --resume cannot check that "
                f"this is the same data")
    keys = [k for k in (keys or _WHAT) if k in saved and k in current]
    diff = [f"{_WHAT[k]} {saved[k]!r} (checkpoint) vs {current[k]!r}" if k not in ("image_names", "image_sizes",
            "pixels", "train") else f"{_WHAT[k]} differ" for k in keys if saved[k] != current[k]]
    if diff:
        raise UserError(f"--resume: {path} was trained on other data: {'; '.join(diff)}; resume with the run's own "
                        f"scene and options, or train into a new --out folder")
    return None


def resume_config(meta, config=None):
    """The config to continue a checkpoint with: the checkpoint's own (fields it lacks at
    their defaults), or ``config`` after checking that it agrees on
    :attr:`TrainConfig.RESUME_KEYS`."""
    # a field the checkpoint lacks: what runs trained with before it existed (``absent``), else its default
    before = {f.name: f.metadata["absent"] for f in fields(TrainConfig) if "absent" in f.metadata}
    saved = {**asdict(TrainConfig()), **before, **meta["config"]}
    saved["background"] = tuple(saved["background"])
    if config is None:
        return TrainConfig(**saved)
    mine = asdict(config)
    mine["background"] = tuple(mine["background"])
    keys = [k for k in TrainConfig.RESUME_KEYS if saved.get(k) != mine.get(k)]
    if keys:
        diff = "; ".join(f"{k} {saved[k]!r} (checkpoint) vs {mine[k]!r}" for k in keys)
        flags = {f.name: f.metadata.get("flag") for f in fields(TrainConfig)}
        hint = [f"{flags[k]} {_flag_value(saved[k])}" for k in keys if flags.get(k)]
        fix = f"pass {' '.join(hint)} to continue it, or" if len(hint) == len(keys) else "use the checkpoint's settings, or"
        raise ValueError(f"--resume: the run's settings differ from the checkpoint's: {diff}; {fix} start again in a "
                         f"new --out folder")
    return config


def _flag_value(value):
    """How ``tsplus train`` spells ``value`` on its command line."""
    if isinstance(value, bool):
        return "on" if value else "off"
    return " ".join(str(v) for v in value) if isinstance(value, (list, tuple)) else str(value)


__all__ = ["CHECKPOINT_VERSION", "CheckpointError", "write_checkpoint", "read_checkpoint", "resume_config",
           "data_fingerprint", "check_fingerprint", "scene_id"]
