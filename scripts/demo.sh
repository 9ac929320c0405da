#!/usr/bin/env bash
# The main job on the small embedded default: render a scene, simulate its spike stream,
# reconstruct it, and print what was done. Sets itself up on a fresh machine.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$here/scripts/bootstrap.sh"
exec "$here/.venv/bin/spikesim" demo "$@"
