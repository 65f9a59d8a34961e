#!/usr/bin/env bash
# Quick start, command 1: set up, then run the main job on the built-in procedural scene.
set -euo pipefail
cd "$(dirname "$0")/.."
bash ci/setup.sh
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-$(mktemp -d)}
exec "${TSPLUS_VENV:-.venv}/bin/tsplus" render "$@"
