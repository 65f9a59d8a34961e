"""tsplus-wgpu: a portable Triangle Splatting+ trainer on WebGPU (wgpu, WGSL).

Public API::

    Camera(width, height, fx, fy, cx, cy, world_to_camera)
    TriangleModel(positions, triangles, sh, opacity)
    DeviceModel.from_model(renderer, model)   # the same on the device (forward skips the upload)
    Renderer(adapter=None).forward(model, camera, sigma, background=(0, 0, 0), near=0.01)
    reference.render(...)   # float64 NumPy twin of the forward pass
"""

from . import reference
from .device_model import DeviceModel
from .mesh_renderer import MeshRenderer
from .renderer import ForwardResult, Renderer
from .types import Camera, TriangleModel

__version__ = "0.1.0"

__all__ = ["Camera", "TriangleModel", "DeviceModel", "MeshRenderer", "Renderer", "ForwardResult", "reference", "__version__"]
