#!/usr/bin/env bash
# Install the CPU build of PyTorch pinned in requirements/cpu.txt into the Python given as $1.
# Where the PyTorch CPU package index answers (https://download.pytorch.org/whl/cpu, or
# $SPIKESIM_TORCH_INDEX), pip is told to look there: the `+cpu` pin then cannot resolve to a CUDA
# build of several GB. Where it does not answer (a closed network with its own package source),
# the same pin is taken from the configured sources, and the message says so.
# `--print` shows the pip command instead of running it (tests/test_bootstrap.py).
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
py="$1"; shift
dry=0; [ "${1:-}" = "--print" ] && dry=1
index="${SPIKESIM_TORCH_INDEX:-https://download.pytorch.org/whl/cpu}"
pin="$(grep -E '^torch==' "$here/requirements/cpu.txt")"
if [ "$(uname -m)" != "x86_64" ]; then
  pin="${pin%+cpu}"   # PyPI's torch for aarch64 is the CPU build, published without the +cpu tag
fi
args=(-m pip install -q "$pin")
if "$py" -c 'import sys, urllib.request; urllib.request.urlopen(sys.argv[1].rstrip("/") + "/torch/", timeout=5)' \
     "$index" >/dev/null 2>&1; then
  args+=(--extra-index-url "$index")
  echo "[bootstrap] torch: $pin from the PyTorch CPU index $index" >&2
else
  echo "[bootstrap] torch: the PyTorch CPU index $index does not answer; taking $pin from the" \
       "configured package sources (pip config list shows them)" >&2
fi
if [ "$dry" = 1 ]; then echo "$py ${args[*]}"; exit 0; fi
"$py" "${args[@]}" 2>&1 | grep -v '^WARNING: Location' || true
if ! "$py" -c 'import torch, sys; sys.exit(0 if torch.version.cuda is None else 1)' 2>/dev/null; then
  echo "[bootstrap] error: no CPU build of torch was installed from $pin (see pip's output above);" \
       "install it by hand, e.g. pip install '$pin' --extra-index-url https://download.pytorch.org/whl/cpu" >&2
  exit 1
fi
