"""The wheel carries shaders/ and viewer/, and the installed package works from
outside the checkout (its shaders found inside the package)."""

import os
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
    pytest.importorskip("hatchling")
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(out),
                    str(ROOT)], check=True, capture_output=True, timeout=300)
    wheels = list(out.glob("tsplus_wgpu-*.whl"))
    assert len(wheels) == 1
    return wheels[0]


def test_wheel_contains_shaders_and_viewer(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    shaders = sorted(p.relative_to(ROOT / "shaders").as_posix() for p in (ROOT / "shaders").rglob("*.wgsl"))
    assert any("/" in s for s in shaders)          # subfolders (common/, render/) too
    for s in shaders:
        assert f"tsplus_wgpu/shaders/{s}" in names, s
    assert "tsplus_wgpu/viewer/__init__.py" in names
    assert any(n.endswith("entry_points.txt") for n in names)


def test_installed_package_runs_outside_checkout(wheel, tmp_path):
    target = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target", str(target), str(wheel)],
                   check=True, capture_output=True, timeout=300)
    env = dict(os.environ)
    # the installed copy first, the dependencies from this environment after it
    env["PYTHONPATH"] = os.pathsep.join([str(target), sysconfig.get_paths()["purelib"]])
    code = ("import tsplus_wgpu, tsplus_wgpu.gpu as g; "
            "assert str(tsplus_wgpu.__file__).startswith(%r), tsplus_wgpu.__file__; "
            "assert str(g.SHADER_DIR).startswith(%r), g.SHADER_DIR; "
            "print(len(g.all_stages()))" % (str(target), str(target)))
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    assert int(out.stdout.strip()) >= 10
    helped = subprocess.run([sys.executable, "-m", "tsplus_wgpu.cli", "--help"], cwd=tmp_path, env=env,
                            capture_output=True, text=True, timeout=120)
    assert helped.returncode == 0 and "bench-raster" in helped.stdout and "render" in helped.stdout
