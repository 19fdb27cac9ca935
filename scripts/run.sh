#!/usr/bin/env bash
# One-step set-up and run for a fresh Linux machine (Python >= 3.11 with venv):
#   bash scripts/run.sh demo [demo options]   set up .venv, then run `splatstyler demo`
#   bash scripts/run.sh test [pytest options] set up .venv with the test extra, then run the whole test suite
# Set-up is idempotent: a second run reuses .venv and only installs what is missing.
set -euo pipefail
cd "$(dirname "$0")/.."

what="${1:-}"
case "$what" in
  demo|test) shift ;;
  *) echo "usage: bash scripts/run.sh demo|test [options]" >&2; exit 2 ;;
esac

PY="${PYTHON:-python3}"
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
VPY=.venv/bin/python
"$VPY" -m pip install --quiet --upgrade pip
# torch first, pinned: it installs offline from local disk on our machines and from PyPI elsewhere; an unpinned
# torch (or one pulled in by another package) would be a multi-GB CUDA build.
"$VPY" -c "import torch" 2>/dev/null || "$VPY" -m pip install --quiet torch==2.13.0
if [ "$what" = test ]; then
  "$VPY" -m pip install --quiet -e ".[test]"
  # Two worker processes, each taking whole test files (module fixtures are built once): on 2 cores the suite took
  # 35.5 min against 45.2 in one process (docs/performance.md, "The test suite"). Options given after override
  # these; -n 0 runs it in one process.
  exec "$VPY" -m pytest -n 2 --dist loadfile "$@"
else
  "$VPY" -m pip install --quiet -e .
  exec .venv/bin/splatstyler demo "$@"
fi
