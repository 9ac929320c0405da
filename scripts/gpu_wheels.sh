#!/usr/bin/env bash
# Download, on a machine that reaches PyPI, the wheels a lent GPU machine lacks, so that
# `scripts/gpu_campaign.sh` runs there the first time (docs/gpu_campaign.md).
#
# The GPU machine: Python 3.12 (cp312), x86-64, CUDA torch, numpy 2.x, scipy, scikit-image,
# pillow, tqdm, imageio, pytest, pytest-timeout and typing_extensions preinstalled; no network.
# It lacks exactly the five packages below. Their own requirements, read from each wheel's
# METADATA (Requires-Dist):
#   drjit 1.5.0          typing_extensions only on Python < 3.11: nothing on 3.12
#   mitsuba 3.9.1        drjit==1.5.0 (below); typing_extensions only on Python < 3.11
#   OpenEXR 3.5.3        numpy>=1.7 (there); Imath ships inside the OpenEXR wheel
#   colour-science 0.4.7 numpy>=2,<3 (there: 2.x)
#   trimesh 5.2.0        numpy>=1.21 (there)
# so no other wheel is needed. Versions: drjit and mitsuba as pinned in pyproject.toml (the ones
# the kernels were measured with); the other three as the development environment has them, so
# the GPU runs the code the tests ran here.
#
# Everything goes into one git-ignored folder (default .whl/, in .gitignore), which a device call
# names in `carry`. Its 64 MiB limit counts the repository's files too: the mitsuba wheel (~63 MB)
# is repacked as .tar.xz (~37 MB; the campaign unpacks it into a folder on PYTHONPATH). The script
# prints the total and fails if the folder plus the working tree exceed 64 MiB.
#
# Usage: bash scripts/gpu_wheels.sh [FOLDER]        (idempotent: what is there is kept)
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$here"
DEST="${1:-$here/.whl}"
LIMIT_BYTES=$((64 * 1024 * 1024))
if [ -x "$here/.venv/bin/python" ]; then PY="${PYTHON:-$here/.venv/bin/python}"; else PY="${PYTHON:-python3}"; fi

MITSUBA="mitsuba==3.9.1"
WHEELS=("drjit==1.5.0" "$MITSUBA" "OpenEXR==3.5.3" "colour-science==0.4.7" "trimesh==5.2.0")
PIP_TARGET=(--only-binary=:all: --no-deps --python-version 3.12 --implementation cp --abi cp312
            --platform manylinux2014_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux_2_28_x86_64)

for tool in unzip xz tar sha256sum; do
  command -v "$tool" >/dev/null || { echo "[gpu_wheels] error: $tool is not installed (apt-get install $tool)" >&2; exit 2; }
done
"$PY" -m pip --version >/dev/null 2>&1 || { echo "[gpu_wheels] error: $PY has no pip (set PYTHON=...)" >&2; exit 2; }
mkdir -p "$DEST"
tarball="$DEST/mitsuba-3.9.1-cp312-manylinux.tar.xz"

for spec in "${WHEELS[@]}"; do
  name="${spec%%==*}"; version="${spec##*==}"
  # wheel file names normalise the project name: lower case, - and . as _
  norm="$(echo "$name" | tr 'A-Z.-' 'a-z__')"
  if [ "$spec" = "$MITSUBA" ] && [ -f "$tarball" ]; then echo "[gpu_wheels] $spec: $tarball already there"; continue; fi
  if ls "$DEST"/ 2>/dev/null | grep -qi "^${norm}-${version}-.*\.whl$"; then
    echo "[gpu_wheels] $spec: already there"; continue
  fi
  # one version of each package: an older wheel beside the new one would stop the install
  find "$DEST" -maxdepth 1 -iname "${norm}-*.whl" -delete
  echo "[gpu_wheels] downloading $spec"
  if ! "$PY" -m pip download -q "${PIP_TARGET[@]}" -d "$DEST" "$spec"; then
    echo "[gpu_wheels] error: could not download $spec (cp312 manylinux x86_64 wheel) from PyPI" >&2
    exit 1
  fi
done

# mitsuba: the wheel's contents (package + dist-info) as .tar.xz, then the wheel is dropped
wheel="$(find "$DEST" -maxdepth 1 -name 'mitsuba-3.9.1-*.whl' | head -1)"
if [ -n "$wheel" ]; then
  echo "[gpu_wheels] repacking $(basename "$wheel") ($(du -m "$wheel" | cut -f1) MB) as .tar.xz (a minute or two)"
  tmp="$(mktemp -d)"
  trap 'rm -rf "$tmp"' EXIT
  unzip -q "$wheel" -d "$tmp/site"
  # -T0: every core; -9: the smallest (decompressing stays fast: ~2 s on the GPU machine)
  tar -C "$tmp/site" -cf - . | nice xz -9 -T0 -c > "$tmp/mitsuba.tar.xz"
  mv "$tmp/mitsuba.tar.xz" "$tarball"
  rm -f "$wheel"
fi

# the manifest the campaign checks before installing (a damaged transfer fails there, by name)
(cd "$DEST" && sha256sum -- *.whl "$(basename "$tarball")" > SHA256SUMS)

# the sizes, and the limit: the wheel folder plus what travels of the working tree (tracked files
# and untracked ones git does not ignore)
"$PY" - "$DEST" "$LIMIT_BYTES" <<'PYEOF'
import os, subprocess, sys
dest, limit = sys.argv[1], int(sys.argv[2])
listed = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
                        capture_output=True, check=True).stdout
names = [n for n in listed.decode().split("\0") if n]
tree = sum(os.path.getsize(n) for n in names if os.path.isfile(n))
wheels = {f: os.path.getsize(os.path.join(dest, f)) for f in sorted(os.listdir(dest))}
mib = lambda b: b / 2**20
for f, b in wheels.items():
    print(f"[gpu_wheels]   {f}: {mib(b):.1f} MiB")
total = tree + sum(wheels.values())
print(f"[gpu_wheels] {dest}: {mib(sum(wheels.values())):.1f} MiB; working tree {mib(tree):.1f} MiB; together "
      f"{mib(total):.1f} MiB of the {mib(limit):.0f} MiB a device call carries")
if total > limit:
    print(f"[gpu_wheels] error: {mib(total):.1f} MiB is over the {mib(limit):.0f} MiB a device call carries: "
          f"remove untracked files from the working tree or wheels from {dest}", file=sys.stderr)
    sys.exit(1)
PYEOF
