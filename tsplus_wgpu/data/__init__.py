"""Scene ingestion: COLMAP, transforms.json, LLFF, photos-only input and videos, plus the
built-in procedural scene.

Main entry points:

* :func:`load_scene` - detect the format of a folder and return a :class:`Scene`.
* :func:`load_procedural` - the built-in, deterministic, textured indoor scene.
* :func:`load_scene_arg` - the scene a command-line argument names (``procedural[:size]`` or a path).
* :func:`demo_model` - the procedural scene's ground-truth mesh as an opaque TriangleModel.
* :class:`SceneError` - raised for a user's data mistake, as one line naming the file and the fix.
* :class:`WorldFrame` - the normalised frame training works in (:meth:`Scene.frame`).
"""

from .errors import SceneError
from .frame import WorldFrame
from .loader import FORMATS, detect_format, load_scene, load_scene_arg
from .procedural import demo_model, load_procedural
from .scene import GTMesh, Scene

__all__ = ["FORMATS", "GTMesh", "Scene", "SceneError", "WorldFrame", "demo_model", "detect_format", "load_procedural",
           "load_scene", "load_scene_arg"]
