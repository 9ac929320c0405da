#!/usr/bin/env bash
# Every GPU measurement and a training run, for a lent GPU machine (docs/gpu_campaign.md): installs
# what the machine lacks from the carried wheel folder (.whl, filled by scripts/gpu_wheels.sh),
# then runs each stage under its own time box into $OUT (or -o): summary.json, logs.txt, report.md
# and the trained weights. On the device, from the repository root, in one call of 9 minutes
# (part one: the stages in order of value, each later one skipped with its reason when time is short):
#   bash scripts/gpu_campaign.sh
# or, for a longer lease, in two calls: --part 1, then --part 2.
# Rehearsal on the CPU at a tiny size: bash scripts/gpu_campaign.sh --dry-run -o out/campaign
# The Python is $PYTHON, else this checkout's .venv for --dry-run, else python3 (a GPU image's,
# which holds CUDA torch). The logic is pipelines/gpu_campaign/; this only picks the interpreter.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$here"
if [ -z "${PYTHON:-}" ]; then
  PYTHON=python3
  case " $* " in *" --dry-run "*) [ -x "$here/.venv/bin/python" ] && PYTHON="$here/.venv/bin/python" ;; esac
fi
export PYTHONUNBUFFERED=1
exec "$PYTHON" -m pipelines.gpu_campaign.cmd "$@"
