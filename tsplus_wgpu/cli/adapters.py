"""``tsplus adapters``: list the GPU adapters wgpu sees, with features and the chosen one."""

from __future__ import annotations

import os

from ..errors import UserError


def add_adapter_arg(p):
    """The ``--adapter`` option of the commands that choose a GPU."""
    p.add_argument("--adapter", default=None,
                   help="GPU adapter to use, matched against its name (e.g. 'nvidia', 'lavapipe'); "
                        "default: TSPLUS_ADAPTER or the best one (discrete GPU first)")


#: :data:`~tsplus_wgpu.gpu.LAYOUTS`, named here so that ``--help`` does not import wgpu (a test
#: holds the two equal)
LAYOUT_NAMES = ("cpu", "gpu", "pixel")


def add_layout_arg(p):
    """The ``--layout`` option of the benchmarks: the blend kernels' layout."""
    p.add_argument("--layout", default=None, choices=LAYOUT_NAMES,
                   help="the blend kernels' layout: cpu (the column kernels: in the forward 8 invocations a "
                        "16x16 tile, two columns of 16 pixels each, in the backward 16, one column each), gpu (one "
                        "invocation a pixel in the forward, the column backward: the faster pair on an NVIDIA H100) "
                        "or pixel (one invocation a pixel in both); default: TSPLUS_LAYOUT or the adapter's type "
                        "(cpu on a CPU adapter such as lavapipe, else gpu)")


def layout_renderer(args):
    """A :class:`~tsplus_wgpu.Renderer` on ``args.adapter`` in ``args.layout``."""
    from ..gpu import GpuContext
    from ..render.renderer import Renderer
    return Renderer(GpuContext(args.adapter, layout=getattr(args, "layout", None)))


def add_parser(sub):
    return sub.add_parser(
        "adapters", help="list the GPU adapters wgpu sees, with features and the chosen one",
        description="List the GPU adapters wgpu sees (Vulkan, Metal, D3D12; Mesa lavapipe on a machine without a "
                    "GPU), each with its type, its optional features (timestamps, float32 atomics, subgroups), its "
                    "storage-binding and buffer-size limits and the kernel layout it gets. The one marked * is what "
                    "every command uses unless --adapter or TSPLUS_ADAPTER chooses another; TSPLUS_WEBGPU_LIMITS=1 "
                    "keeps WebGPU's default limits, TSPLUS_LAYOUT=cpu|gpu|pixel sets the layout.")


def run(args):
    from ..gpu.context import (LAVAPIPE_HINT, WEBGPU_DEFAULT_LIMITS, adapter_description, adapter_size_limits,
                               choose_layout, list_adapters, select_adapter)
    adapters = list_adapters()
    if not adapters:
        raise UserError(LAVAPIPE_HINT)
    chosen = select_adapter(os.environ.get("TSPLUS_ADAPTER"))
    for a in adapters:
        mark = "*" if a is chosen or a.info == chosen.info else " "
        feats = set(a.features)
        opt = [name for key, name in (("timestamp-query", "timestamps"), ("shader-float32-atomic", "float32-atomics"),
                                      ("subgroup", "subgroups")) if key in feats]
        size = (WEBGPU_DEFAULT_LIMITS if os.environ.get("TSPLUS_WEBGPU_LIMITS") == "1"     # what a device gets
                else adapter_size_limits(dict(a.limits)))
        print(f"{mark} {adapter_description(a)}  [{', '.join(opt) or 'no optional features'}]  "
              f"{size['max-storage-buffer-binding-size'] / 2**20:,.0f} MiB per binding, "
              f"{size['max-buffer-size'] / 2**20:,.0f} MiB per buffer, {choose_layout(dict(a.info))} kernel layout")
    print("(* = used by default; set TSPLUS_ADAPTER or --adapter to choose; "
          "TSPLUS_WEBGPU_LIMITS=1 keeps WebGPU's 128 MiB per binding and 256 MiB per buffer; "
          "TSPLUS_LAYOUT=cpu|gpu|pixel sets the kernel layout)")
    return 0
