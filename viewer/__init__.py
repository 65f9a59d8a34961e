"""Live preview window for tsplus-wgpu (rendercanvas + wgpu), built only on the public API.

Shipped inside the wheel as ``tsplus_wgpu.viewer``. The window itself is the subject of
the live-preview issue and is not implemented yet; nothing here claims otherwise.
"""
