"""Training: configuration, the trainer, its vertex state, topology strategy, schedules, losses.

* :mod:`.config` - :class:`TrainConfig` (every default once, with help text and CLI flag).
* :mod:`.trainer` - :class:`Trainer`, the loop behind ``tsplus train`` (one step on the device,
  checkpoints, evaluation, the final mesh); :mod:`.loop` runs its :meth:`Trainer.train`.
* :mod:`.callbacks` - :class:`TrainCallback`, hooks on the real training loop (benchmarks).
* :mod:`.state` - :class:`VertexState`, the per-vertex arrays (parameters, Adam moments) and the
  triangles on the host.
* :mod:`.strategy` - pure topology operations on a :class:`VertexState` (prune, densify, remove
  unused vertices) and :class:`~.strategy.TopologyStrategy`, the pre/post-step hooks.
* :mod:`.schedules` - every schedule of method.md (:class:`Schedule`), opacity-floor logit mapping.
* :mod:`.init` - :func:`init_from_points` (SfM points -> Delaunay faces -> TriangleModel).
* :mod:`.losses`, :mod:`.normals` - the image loss and the optional normal loss on the device.
* :mod:`.profile` - per-stage timing of a step; :mod:`.ablations` - the paper's ablation rows.

:class:`Trainer` imports the device modules (wgpu); it is loaded on first use.
"""

from .callbacks import TrainCallback
from .config import TrainConfig
from .init import InitInfo, delaunay_faces, init_from_points
from .schedules import Schedule, logit_from_opacity, opacity_from_logit, reinvert_logits
from .state import VertexState


def __getattr__(name):
    if name == "Trainer":
        from .trainer import Trainer
        return Trainer
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["Trainer", "TrainConfig", "TrainCallback", "VertexState", "Schedule", "opacity_from_logit",
           "logit_from_opacity", "reinvert_logits", "init_from_points", "delaunay_faces", "InitInfo"]
