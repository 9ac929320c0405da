#!/usr/bin/env bash
# The held-out scoring of issue 39 (docs/model.md, "The fourth stage"): every test set, every
# classic method and floor, the shipped networks. Usage: bash scripts/issue39_eval.sh [EXTRA_METHOD ...]
# (e.g. new=runs/lrrep_v3/best.pt); DATASETS="llr_small5 ..." scores only those (EXTERNAL=1 adds the
# external pair and the real recording); NETS="lrrep" scores only those shipped networks; OUT=DIR
# writes there instead of out/issue39. Data made by the commands in docs/model.md; the external pair
# (spk2imgnet-sample/) and the real recording (uhsr-real/) are read from $SPIKESIM_TEST_DATA, as the
# tests read them (tests/conftest.py), and skipped where absent.
set -euo pipefail
cd "$(dirname "$0")/.."
S=.venv/bin/spikesim
SHARED="${SPIKESIM_TEST_DATA:-}"
NETS="${NETS:-lrrep lrrep_v2 lrrep_v1}"   # the shipped networks to score (NETS="lrrep" for the newest only)
M="tfp tfi tfp:123 tfp:205 stp snm black mean $NETS $*"
OUT="${OUT:-out/issue39}"
mkdir -p "$OUT"
# llr_small5_gt256 and llr_small5_s77{27,37,47}: the 64 x 100 yardstick, four test seeds at a 256-spp ground
# truth (docs/model.md, "The 64 x 100 yardstick"); pool a case over them by hand (the mean of the four);
# llr_mid5_gt256 and llr_paper5_gt256: the larger sets' streams with a 256-spp ground truth
for d in ${DATASETS:-llr_small5 llr_mid5 llr_paper5 reds_like12 test_nat6 llr_small5_gt256 llr_small5_s7727 llr_small5_s7737 llr_small5_s7747 llr_mid5_gt256 llr_paper5_gt256}; do
  [ -d "data/$d" ] || { echo "[issue39] no data/$d, skipped"; continue; }
  $S evaluate --data "data/$d" --methods $M -o "$OUT/$d" --quiet > "$OUT/$d.md"
  echo "[issue39] scored data/$d"
done
[ -n "${DATASETS:-}" ] && [ -z "${EXTERNAL:-}" ] && exit 0  # a part of the sets only: the external data once
if [ -n "$SHARED" ] && [ -f "$SHARED/spk2imgnet-sample/203_part1_key_id151.dat" ]; then
  $S evaluate --dat "$SHARED/spk2imgnet-sample/203_part1_key_id151.dat" --gt "$SHARED/spk2imgnet-sample/203_part1_key_id151.png" \
     --center 151 --gt-scale 0.6 --methods $M --json > $OUT/spk2imgnet_sample.json
fi
if [ -n "$SHARED" ] && [ -f "$SHARED/uhsr-real/uhsr_helicopter.dat" ]; then
  $S panel "$SHARED/uhsr-real/uhsr_helicopter.dat" --height 250 --width 250 --methods tfp tfp:205 $NETS $* \
     -o $OUT/uhsr_panel.png --json > $OUT/uhsr_panel.json
fi
