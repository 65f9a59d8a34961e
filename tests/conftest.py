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


def pytest_report_header(config):
    try:
        from tsplus_wgpu.gpu import adapter_description, select_adapter
        return f"tsplus adapter: {adapter_description(select_adapter())}"
    except Exception as exc:  # pragma: no cover
        return f"tsplus adapter: none ({exc})"
