"""Training building blocks: schedules, initialisation, loss on the device, Adam on the device.

* :mod:`.schedules` - every schedule of method.md (:class:`Schedule`), opacity-floor logit mapping.
* :mod:`.init` - :func:`init_from_points` (SfM points -> Delaunay faces -> TriangleModel).
* :mod:`.losses` - :class:`ImageLoss` (0.8 L1 + 0.2 (1 - SSIM) and its image gradient, WGSL) and
  the float64 twin :func:`image_loss_reference`.
* :mod:`.optim` - :class:`Adam` (WGSL, one dispatch per parameter group) and :func:`adam_reference`.
* :mod:`.kernels` - the trainer's small kernels (opacity activation, parameter gradients, v_image
  packing, early opacity loss) with float64 twins.
* :mod:`.normals` - the optional normal loss (:class:`~.normals.NormalLoss`, WGSL, both gradient
  paths) and its float64 twin; the priors are read by :mod:`tsplus_wgpu.data.normals`.
* :mod:`.trainer` - :class:`~.trainer.Trainer` and :class:`~.trainer.TrainConfig`, the loop behind
  ``tsplus train`` (:mod:`.cli`). Pruning/densification during training are not implemented yet
  (see the trainer's module docstring).

The device modules import wgpu; they are loaded on first use.
"""

from .init import InitInfo, delaunay_faces, init_from_points
from .schedules import Schedule, logit_from_opacity, opacity_from_logit, reinvert_logits

__all__ = ["Schedule", "opacity_from_logit", "logit_from_opacity", "reinvert_logits", "init_from_points",
           "delaunay_faces", "InitInfo"]
