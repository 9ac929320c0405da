#!/usr/bin/env bash
# Set up everything the project needs on a fresh machine, idempotently:
#  - libLLVM >= 17 for Dr.Jit's CPU backend (Debian's libllvm19; docs/design.md section 6),
#  - a virtual environment in .venv with torch pinned to the CPU build (requirements/cpu.txt)
#    and this project installed in editable mode with every extra (the tests and the demo use
#    them all: test, train, plot, video, cluster; pyproject.toml).
# Sourcing is not needed: scripts/demo.sh and scripts/test.sh call it.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$here"
PY="${PYTHON:-python3}"
VENV="$here/.venv"

if ! "$PY" -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null; then
  echo "[bootstrap] error: spikesim needs Python >= 3.11 (tomllib); $PY is $("$PY" -V 2>&1)." \
       "Set PYTHON=python3.11 (or newer)" >&2
  exit 1
fi

find_libllvm() {
  for f in /usr/lib/x86_64-linux-gnu/libLLVM.so.19.1 /usr/lib/x86_64-linux-gnu/libLLVM-19.so \
           /usr/lib/aarch64-linux-gnu/libLLVM.so.19.1 /usr/lib/aarch64-linux-gnu/libLLVM-19.so \
           /usr/lib/llvm-19/lib/libLLVM.so /usr/lib/llvm-18/lib/libLLVM.so /usr/lib/llvm-17/lib/libLLVM.so; do
    [ -e "$f" ] && { echo "$f"; return 0; }
  done
  return 1
}

if ! find_libllvm >/dev/null; then
  echo "[bootstrap] installing libllvm19 (Dr.Jit's LLVM backend needs libLLVM >= 17)"
  SUDO=""; [ "$(id -u)" != 0 ] && SUDO="sudo"
  if ! command -v apt-get >/dev/null; then
    echo "[bootstrap] error: no apt-get; install libLLVM >= 17 and set DRJIT_LIBLLVM_PATH" >&2; exit 1
  fi
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq libllvm19 >/dev/null
fi

stamp="$VENV/.bootstrap-stamp"
want="$(cat pyproject.toml requirements/cpu.txt | sha256sum | cut -c1-16)"
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  echo "[bootstrap] creating/updating virtual environment in .venv"
  [ -x "$VENV/bin/python" ] || "$PY" -m venv "$VENV"
  "$VENV/bin/python" -m pip install -q --upgrade pip 2>&1 | grep -v '^WARNING: Location' || true
  # torch first, so the project's `torch>=...` range is satisfied by the CPU build.
  bash "$here/scripts/torch_cpu.sh" "$VENV/bin/python"
  # PYTHONWARNINGS reaches the build backend: setuptools' "Editable installation" warning block
  # (about folders named like the package) says nothing a user of this checkout needs.
  echo "[bootstrap] installing spikesim and its extras (mitsuba, drjit, OpenEXR, ...; about a minute)"
  PYTHONWARNINGS=ignore "$VENV/bin/python" -m pip install -q -e ".[test,train,plot,video,cluster]" 2>&1 \
    | grep -v '^WARNING: Location' || true
  "$VENV/bin/python" -c "import torch, drjit, mitsuba, spikesim" 
  echo "$want" > "$stamp"
fi
