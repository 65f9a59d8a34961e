#!/usr/bin/env bash
# Quick start, command 2: set up, then run the whole test suite (headless; lavapipe
# when there is no GPU). Extra arguments go to pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
bash ci/setup.sh
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-$(mktemp -d)}
exec "${TSPLUS_VENV:-.venv}/bin/python" -m pytest -q -ra "$@"
