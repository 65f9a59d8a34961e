#!/usr/bin/env bash
# Quick start, command 1: set up, then run the main job: train on the built-in procedural
# scene (quick preset, 3000 iterations, topology on; about 8-10 minutes on lavapipe with 2 cores) and write
# runs/demo/ (mesh.ply, metrics.json, test renders, log.jsonl). Extra arguments go to
# `tsplus train`.
set -euo pipefail
cd "$(dirname "$0")/.."
bash ci/setup.sh
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-$(mktemp -d)}
exec "${TSPLUS_VENV:-.venv}/bin/tsplus" train --out runs/demo --preset quick "$@"
