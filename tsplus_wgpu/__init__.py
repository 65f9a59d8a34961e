"""tsplus-wgpu: a portable Triangle Splatting+ trainer on WebGPU (wgpu, WGSL).

Public API::

    Camera(width, height, fx, fy, cx, cy, world_to_camera)
    TriangleModel(positions, triangles, sh, opacity)
    DeviceModel.from_model(renderer, model)   # the same on the device (forward skips the upload)
    Renderer(adapter=None).forward(model, camera, sigma, background=(0, 0, 0), near=0.01)
    MeshRenderer(adapter=None).render(model, camera)   # depth-tested opaque mesh, as an engine draws it
    reference.render(...)   # float64 NumPy twin of the forward pass

    scene = load_scene("path/to/scene")  or  load_procedural("small")   # or load_scene_arg("procedural:tiny")
    trainer = Trainer(scene, TrainConfig(iterations=3000, quick=True)); trainer.train()
    export(model, "mesh.glb"); model, info = load_run("runs/x"); model = read_mesh("mesh.ply")
    up = estimate_up(scene.cameras); export(model, "mesh.glb", rotation=engine_rotation(up))   # upright

Training, scene loading and export are loaded on first use.
"""

from importlib import import_module

from . import reference
from .render.device_model import DeviceModel
from .render.mesh_renderer import MeshRenderer
from .render.renderer import ForwardResult, Renderer
from .types import Camera, TriangleModel

__version__ = "0.1.0"

#: public name -> the module that defines it (imported on first access)
_LAZY = {
    "Trainer": ".train.trainer", "TrainConfig": ".train.trainer",
    "Scene": ".data", "SceneError": ".data", "load_scene": ".data", "load_procedural": ".data",
    "load_scene_arg": ".data", "demo_model": ".data", "WorldFrame": ".data",
    "export": ".io.export", "load_run": ".apps.runs", "read_mesh": ".io.export", "ExportError": ".io.export",
    "UserError": ".errors",
    "clip_from_camera": ".render.mesh_renderer", "load_wgsl": ".gpu.wgsl",
    "MeshCollider": ".apps.collider", "find_placement": ".apps.placement", "PlacementError": ".apps.placement",
    "estimate_up": ".data.upright", "engine_rotation": ".data.upright",
}


def __getattr__(name):
    if name in _LAZY:
        value = getattr(import_module(_LAZY[name], __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))


__all__ = ["Camera", "TriangleModel", "DeviceModel", "MeshRenderer", "Renderer", "ForwardResult", "reference",
           "__version__", *_LAZY]
