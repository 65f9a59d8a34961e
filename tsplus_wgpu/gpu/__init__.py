"""The wgpu runtime: adapters and the device (:mod:`.context`), the WGSL loader
(:mod:`.wgsl`), the host side of one kernel (:mod:`.stage`) and timing (:mod:`.recorder`)."""

from .context import (LAVAPIPE_HINT, LAYOUT_KERNELS, LAYOUTS, SIZE_LIMIT_CAP, SIZE_LIMITS, WEBGPU_DEFAULT_LIMITS, Features, GpuContext,
                      NoAdapterError, adapter_description, choose_layout, layout_kernel, adapter_size_limits, list_adapters, select_adapter)
from .recorder import Recorder, host_time
from .stage import Scratch, Stage, grid, groups
from .wgsl import (SHADER_DIR, Binding, WgslSource, all_stages, constant, kernel_group, load_wgsl, resolve_imports,
                   shader_path,
                   struct_dtype)

__all__ = ["LAVAPIPE_HINT", "LAYOUT_KERNELS", "LAYOUTS", "SIZE_LIMIT_CAP", "SIZE_LIMITS", "WEBGPU_DEFAULT_LIMITS", "Features", "GpuContext",
           "NoAdapterError", "adapter_description", "choose_layout", "layout_kernel", "adapter_size_limits", "list_adapters", "select_adapter", "Recorder", "host_time", "Scratch",
           "Stage", "grid", "groups", "SHADER_DIR", "Binding", "WgslSource", "all_stages", "constant", "kernel_group", "load_wgsl", "shader_path",
           "resolve_imports", "struct_dtype"]
