#!/usr/bin/env bash
# The held-out scoring of issue 39 (docs/model.md, "The fourth stage"): every test set, every
# classic method and floor, the shipped networks. Usage: bash scripts/issue39_eval.sh [EXTRA_METHOD ...]
# (e.g. new=runs/lrrep_v3/best.pt); DATASETS="llr_small5 ..." scores only those (EXTERNAL=1 adds the
# external pair and the real recording). Data made by the commands in docs/model.md; the external pair
# (spk2imgnet-sample/) and the real recording (uhsr-real/) are read from $SPIKESIM_TEST_DATA, as the
# tests read them (tests/conftest.py), and skipped where absent.
set -euo pipefail
cd "$(dirname "$0")/.."
S=.venv/bin/spikesim
SHARED="${SPIKESIM_TEST_DATA:-}"
M="tfp tfi tfp:123 tfp:205 stp snm black mean lrrep lrrep_v2 lrrep_v1 $*"
mkdir -p out/issue39
for d in ${DATASETS:-llr_small5 llr_mid5 llr_paper5 reds_like12 test_nat6}; do
  [ -d "data/$d" ] || { echo "[issue39] no data/$d, skipped"; continue; }
  $S evaluate --data "data/$d" --methods $M -o "out/issue39/$d" --quiet > "out/issue39/$d.md"
  echo "[issue39] scored data/$d"
done
[ -n "${DATASETS:-}" ] && [ -z "${EXTERNAL:-}" ] && exit 0  # a part of the sets only: the external data once
if [ -n "$SHARED" ] && [ -f "$SHARED/spk2imgnet-sample/203_part1_key_id151.dat" ]; then
  $S evaluate --dat "$SHARED/spk2imgnet-sample/203_part1_key_id151.dat" --gt "$SHARED/spk2imgnet-sample/203_part1_key_id151.png" \
     --center 151 --gt-scale 0.6 --methods $M --json > out/issue39/spk2imgnet_sample.json
fi
if [ -n "$SHARED" ] && [ -f "$SHARED/uhsr-real/uhsr_helicopter.dat" ]; then
  $S panel "$SHARED/uhsr-real/uhsr_helicopter.dat" --height 250 --width 250 --methods tfp tfp:205 lrrep lrrep_v2 lrrep_v1 $* \
     -o out/issue39/uhsr_panel.png --json > out/issue39/uhsr_panel.json
fi
