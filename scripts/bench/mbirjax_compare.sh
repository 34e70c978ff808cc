#!/usr/bin/env bash
# Runs scripts/bench/mbirjax_compare.py in a virtual environment under target/.
#   scripts/bench/mbirjax_compare.sh --install   create target/mbirjax-venv and pip install mbirjax
#   scripts/bench/mbirjax_compare.sh [ARGS]      compare (ARGS go to the Python script)
# Not part of CI or the test command: it needs PyPI and a few minutes.
set -euo pipefail
repo="$(cd "$(dirname "$0")/../.." && pwd)"
venv="$repo/target/mbirjax-venv"
if [[ "${1:-}" == "--install" ]]; then
    shift
    python3 -m venv "$venv"
    "$venv/bin/pip" install --upgrade pip
    "$venv/bin/pip" install mbirjax
fi
if [[ ! -x "$venv/bin/python" ]]; then
    echo "no virtual environment at $venv: run $0 --install first" >&2
    exit 2
fi
exec "$venv/bin/python" "$repo/scripts/bench/mbirjax_compare.py" "$@"
