#!/usr/bin/env bash
# Set up tsplus-wgpu on this machine: Python (when missing), the virtual environment
# with the package, and a Vulkan driver when wgpu finds no Vulkan adapter (Mesa's
# lavapipe runs everything on the CPU). Safe to run again: it only does what is missing.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${TSPLUS_VENV:-.venv}

as_root() {
    if [ "$(id -u)" = 0 ]; then "$@"
    elif command -v sudo >/dev/null 2>&1; then sudo "$@"
    else echo "ci/setup.sh: need root to run: $*" >&2; exit 1
    fi
}

apt_install() {
    if ! command -v apt-get >/dev/null 2>&1; then
        echo "ci/setup.sh: please install with your package manager: $*" >&2
        exit 1
    fi
    if [ -z "${_APT_UPDATED:-}" ]; then
        as_root apt-get update -qq
        _APT_UPDATED=1
    fi
    as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "$@" >/dev/null
}

# 1. Python 3.10+ with venv
if ! command -v python3 >/dev/null 2>&1 || ! python3 -c 'import sys; assert sys.version_info >= (3, 10)' 2>/dev/null; then
    apt_install python3 python3-venv python3-pip
fi
if ! python3 -c 'import venv, ensurepip' >/dev/null 2>&1; then
    apt_install python3-venv
fi

# 2. The virtual environment and the package (editable, with the test extras)
if [ ! -x "$VENV/bin/python" ]; then
    python3 -m venv "$VENV"
fi
stamp="$VENV/.tsplus-installed"
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
    "$VENV/bin/python" -m pip install -q --upgrade pip >/dev/null
    "$VENV/bin/python" -m pip install -q -e '.[test]'
    touch "$stamp"
fi

# 3. A Vulkan adapter: install lavapipe only when wgpu sees none
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-$(mktemp -d)}
if ! "$VENV/bin/python" -c 'import sys; from tsplus_wgpu.gpu import list_adapters; sys.exit(0 if list_adapters() else 1)' 2>/dev/null; then
    echo "ci/setup.sh: no Vulkan adapter found; installing Mesa's lavapipe (mesa-vulkan-drivers)"
    apt_install mesa-vulkan-drivers libvulkan1
    "$VENV/bin/python" -c 'import sys; from tsplus_wgpu.gpu import list_adapters; sys.exit(0 if list_adapters() else 1)' \
        || { echo "ci/setup.sh: still no Vulkan adapter after installing lavapipe" >&2; exit 1; }
fi

# 4. The viewer's window tests: Xvfb (a virtual display) and the GLFW library, when missing
if ! command -v Xvfb >/dev/null 2>&1; then
    apt_install xvfb
fi
if ! "$VENV/bin/python" -c 'import glfw' >/dev/null 2>&1; then
    apt_install libglfw3
fi

# 5. The Khronos glTF validator for the export tests (node + npm only when node is missing)
if ! command -v node >/dev/null 2>&1 || ! command -v npm >/dev/null 2>&1; then
    apt_install nodejs npm
fi
if [ ! -f .tools/node_modules/gltf-validator/package.json ]; then
    npm install --prefix .tools --no-audit --no-fund -q gltf-validator >/dev/null
fi
"$VENV/bin/tsplus" adapters
