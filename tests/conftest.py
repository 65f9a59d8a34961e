import os
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))  # tests/scenes.py


@pytest.fixture(scope="session")
def renderer():
    from tsplus_wgpu import Renderer
    from tsplus_wgpu.gpu import NoAdapterError
    try:
        return Renderer(os.environ.get("TSPLUS_ADAPTER"))
    except NoAdapterError as exc:  # pragma: no cover - CI installs lavapipe
        pytest.fail(str(exc))


@pytest.fixture(scope="session")
def ctx(renderer):
    return renderer.ctx


@pytest.fixture(scope="session")
def layout_renderers(renderer):
    """A renderer per kernel layout (``GpuContext.layout``) on the test adapter: the session's
    own for its layout, another device for the other, so CI tests both on lavapipe."""
    from tsplus_wgpu import Renderer
    from tsplus_wgpu.gpu import LAYOUTS, GpuContext
    return {name: renderer if name == renderer.ctx.layout else Renderer(GpuContext(renderer.ctx.adapter, layout=name))
            for name in LAYOUTS}


@pytest.fixture(scope="module")      # module: a module may have its own renderer
def binding_renderer(renderer):
    """A renderer whose storage bindings are smaller than its buffers, as the tests of arrays
    past one binding need: the session's own where they are (llvmpipe: 128 MiB against 2 GiB),
    else one at WebGPU's default sizes (128 MiB against 256 MiB), on an adapter that binds a
    whole buffer (an H100: 2 GiB both) where those tests would otherwise skip."""
    from tsplus_wgpu import Renderer
    from tsplus_wgpu.gpu import GpuContext
    lim = renderer.ctx.limits
    if lim["max-storage-buffer-binding-size"] < lim["max-buffer-size"]:
        return renderer
    return Renderer(GpuContext(renderer.ctx.adapter, limits="webgpu", layout=renderer.ctx.layout))



@pytest.fixture
def cup_near(monkeypatch):
    """``(scene, order)``: the cup as its COLMAP model gives it (no points) and the indices of its
    photos by distance from the camera of ``1.jpg``, nearest first (small overlapping sets for the
    SfM tests), with SfM on its default single thread, which repeats. Skipped without the data."""
    import numpy as np
    from tsplus_wgpu.data import load_scene
    data = Path(os.environ.get("TSPLUS_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
    if not (data / "cup").is_dir():
        pytest.skip(f"shared data scene {data / 'cup'} not found (set TSPLUS_DATA)")
    monkeypatch.delenv("TSPLUS_SFM_THREADS", raising=False)
    ref = load_scene(data / "cup", split="none", points="none")
    centres = np.stack([c.center for c in ref.cameras])
    return ref, np.argsort(np.linalg.norm(centres - centres[ref.image_names.index("1.jpg")], axis=1))

def pytest_report_header(config):
    try:
        from tsplus_wgpu.gpu import adapter_description, select_adapter
        return f"tsplus adapter: {adapter_description(select_adapter())}"
    except Exception as exc:  # pragma: no cover
        return f"tsplus adapter: none ({exc})"
