"""Live preview window for tsplus-wgpu (rendercanvas + wgpu), built only on the public API.

Shipped inside the wheel as ``tsplus_wgpu.viewer``:

* :class:`Viewer` shows a :class:`ModelSource` (a file's model) or a :class:`TrainerSource`
  (a live trainer's device buffers, drawn without a copy) in a glfw window, or in an offscreen
  canvas for headless images; :meth:`Viewer.training_hook` draws between training steps at a
  capped frame rate.
* :mod:`.frames`: the sources and :class:`FrameRenderer` (one frame into any colour target).
* :mod:`.controls`: orbit / pan / zoom / fly camera math and the event mapping (no window).
* :mod:`.font`: the HUD's bitmap font.
* :mod:`.walk`: first-person walking with gravity and collision against the mesh (``--walk``).
"""

from .app import NO_DISPLAY_HINT, NoDisplayError, Viewer, display_problem
from .frames import FrameRenderer, ModelSource, TrainerSource
from .controls import InputController, OrbitCamera
from .walk import WalkController, WalkInput

__all__ = ["Viewer", "ModelSource", "TrainerSource", "FrameRenderer", "OrbitCamera", "InputController",
           "NoDisplayError", "display_problem", "NO_DISPLAY_HINT", "WalkController", "WalkInput"]
