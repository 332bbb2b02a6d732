#!/usr/bin/env bash
# Large captures in bounded memory (issue 12): makes 16-bit RGB synthetic captures of the given
# sizes under a 24-light dome, runs `recursive` on each with --memory-limit, and prints per size
# the whole-run time, the peak RSS (report.json memory.peak_rss, from VmHWM), the plan and the
# mean angular error against the ground truth.
#
#   benches/large_capture.sh DIR [LIMIT] [SIZE...]
#   benches/large_capture.sh /big/scratch 3G 2000x1500 4000x3000 8000x6000   # the acceptance runs
#   benches/large_capture.sh /tmp/lc 400M 1000x750 2000x1500                 # a small try
#   benches/large_capture.sh /big/scratch min 2000x1500 4000x3000 8000x6000  # each at its smallest budget
#
# LIMIT `min` runs each capture at the smallest budget that works (the one a refusal names).
#
# Captures are made once (kept in DIR/cap-SIZE); results go to DIR/run-SIZE. Needs jq or python3.
set -euo pipefail
DIR=${1:?usage: $0 DIR [LIMIT] [SIZE...]}
LIMIT=${2:-3G}
shift $(( $# >= 2 ? 2 : $# ))
SIZES=("$@")
[ ${#SIZES[@]} -gt 0 ] || SIZES=(2000x1500 4000x3000 8000x6000)
ROOT=$(cd "$(dirname "$0")/.." && pwd)
B=${PHOTOSTEREO:-$ROOT/target/release/photostereo}
[ -x "$B" ] || (cd "$ROOT" && cargo build --release -p photostereo-cli)
mkdir -p "$DIR"
field() { python3 -c "import json,sys; r=json.load(open(sys.argv[1])); v=r
for k in sys.argv[2].split('.'): v=v.get(k) if isinstance(v, dict) else None
print(v)" "$1" "$2"; }
printf '%-11s %9s %10s %8s %12s %-22s %8s %9s\n' size synth_s run_s limit peak_rss_MB layout tiles mean_deg
for S in "${SIZES[@]}"; do
  CAP=$DIR/cap-$S
  T0=$(date +%s.%N)
  if [ ! -f "$CAP/synth.json" ]; then
    "$B" synth terrain --rig dome-24 --size "$S" --brdf blinn-phong --noise 0.005 --seed 1 \
      --memory-limit "$([ "$LIMIT" = min ] && echo 3G || echo "$LIMIT")" -o "$CAP" --force --quiet
  fi
  RUN_LIMIT=$LIMIT
  if [ "$LIMIT" = min ]; then
    RUN_LIMIT=$("$B" run "$CAP" --memory-limit 1M -o "$DIR/refused-$S" --quiet 2>&1 | sed -n 's/.*smallest budget that works is //p' || true)
  fi
  T1=$(date +%s.%N)
  "$B" run "$CAP" --gt "$CAP/gt/normal.npy" --memory-limit "$RUN_LIMIT" -o "$DIR/run-$S" --force --quiet
  T2=$(date +%s.%N)
  R=$DIR/run-$S/report.json
  printf '%-11s %9.1f %10.1f %8s %12.0f %-22s %8s %9.4f\n' "$S" "$(echo "$T1 - $T0" | bc)" "$(echo "$T2 - $T1" | bc)" "$RUN_LIMIT" \
    "$(echo "$(field "$R" memory.peak_rss) / 1000000" | bc -l)" "$(field "$R" memory.layout | tr ' ' _)" \
    "$(field "$R" memory.tiles)" "$(field "$R" error.mean_deg)"
done
