"""Reading and checking trainer checkpoints (``checkpoint.npz``).

A checkpoint is an ``.npz`` of the trainer's arrays in the device layout
(:meth:`~.trainer.Trainer.state_arrays`: ``positions``, ``sh_planar``, ``logits``, ``triangles``,
``exp_avg_<p>`` / ``exp_avg_sq_<p>``), the topology's ``max_weight_acc`` and ``l1_ring``, and
``meta`` (JSON bytes: ``version``, ``iteration``, ``elapsed``, ``topology``, ``config``,
``adapter``). :func:`tsplus_wgpu.apps.runs.load_run` reads the same files.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np

from .config import TrainConfig

CHECKPOINT_VERSION = 1


def read_checkpoint(path):
    """``(arrays, meta)`` of the checkpoint at ``path`` (a ``--resume`` error otherwise)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"--resume: no checkpoint at {path}")
    try:
        with np.load(path) as z:
            arrays = {k: z[k] for k in z.files}
        meta = json.loads(bytes(arrays.pop("meta")).decode())
    except Exception as exc:
        raise ValueError(f"--resume: {path} is not a readable tsplus checkpoint ({exc})") from None
    if meta.get("version") != CHECKPOINT_VERSION:
        raise ValueError(f"--resume: {path} has checkpoint version {meta.get('version')}, "
                         f"this tsplus reads {CHECKPOINT_VERSION}")
    return arrays, meta


def resume_config(meta, config=None):
    """The config to continue a checkpoint with: the checkpoint's own (fields it lacks at
    their defaults), or ``config`` after checking that it agrees on
    :attr:`TrainConfig.RESUME_KEYS`."""
    saved = {**asdict(TrainConfig()), **meta["config"]}
    saved["background"] = tuple(saved["background"])
    if config is None:
        return TrainConfig(**saved)
    mine = asdict(config)
    mine["background"] = tuple(mine["background"])
    diff = [f"{k} {saved[k]!r} (checkpoint) vs {mine[k]!r}" for k in TrainConfig.RESUME_KEYS
            if saved.get(k) != mine.get(k)]
    if diff:
        raise ValueError(f"--resume: the run's settings differ from the checkpoint's: {'; '.join(diff)}")
    return config


__all__ = ["CHECKPOINT_VERSION", "read_checkpoint", "resume_config"]
