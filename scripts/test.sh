#!/usr/bin/env bash
# The default (fast) test suite; pass `-m slow` or other pytest arguments to change it.
# Sets itself up on a fresh machine.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$here/scripts/bootstrap.sh"
cd "$here"
exec "$here/.venv/bin/python" -m pytest -m "not slow and not gpu" -q "$@"
