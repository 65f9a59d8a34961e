#!/usr/bin/env bash
# Quick start, command 2: set up, then run the whole test suite (headless; lavapipe
# when there is no GPU). Extra arguments go to pytest.
# Two pytest-xdist workers by default (TSPLUS_TEST_WORKERS=N for N, 1 for one process): the
# tests spend about half their time in Python between dispatches, so on 2 cores two workers
# took 755 s where one took 1,188 (docs/testing.md).
set -euo pipefail
cd "$(dirname "$0")/.."
bash ci/setup.sh
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-$(mktemp -d)}
py="${TSPLUS_VENV:-.venv}/bin/python"
workers=${TSPLUS_TEST_WORKERS:-2}
case "$workers" in
    ''|*[!0-9]*) echo "ci/test.sh: TSPLUS_TEST_WORKERS='$workers': expected a whole number of workers, e.g. 2 or 1" >&2; exit 2 ;;
esac
parallel=()
if [ "$workers" -gt 1 ] && "$py" -c 'import xdist' >/dev/null 2>&1; then
    parallel=(-n "$workers" --dist loadfile)   # a file's tests on one worker: its module fixtures are built once
fi
exec "$py" -m pytest -q -ra ${parallel[@]+"${parallel[@]}"} "$@"
