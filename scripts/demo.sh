#!/usr/bin/env bash
# The built-in demo: simulate the two-floor building (skipped when already there), build its map,
# score it against the simulator's ground truth, and say where everything is.
set -euo pipefail
cd "$(dirname "$0")/.."
MFMAP=${MFMAP:-.venv/bin/mfmap}
WORK=${WORK:-work}
SCENARIO=${SCENARIO:-two-floor}
SIM="$WORK/sim-$SCENARIO"
OUT="$WORK/build-$SCENARIO"

if [ ! -f "$SIM/.complete" ]; then
    echo "== simulate $SCENARIO -> $SIM"
    rm -rf "$SIM"
    "$MFMAP" simulate "$SCENARIO" -o "$SIM" --plot
    touch "$SIM/.complete"
else
    echo "== simulate $SCENARIO: already in $SIM (delete it to regenerate)"
fi

echo "== info"
"$MFMAP" info "$SIM/log.mcap"

echo "== build -> $OUT"
"$MFMAP" build "$SIM/log.mcap" -o "$OUT" --force

echo "== eval against ground truth"
"$MFMAP" eval "$OUT" \
    --points "$SIM/gt_points.csv" \
    --trajectory "$SIM/gt_trajectory.tum" \
    --floors "$SIM/gt_floors.json" \
    --cloud "$SIM/gt_cloud.ply"

echo
echo "Outputs:"
echo "  log and ground truth : $SIM/"
echo "  map                  : $OUT/map.ply, $OUT/trajectory.tum, $OUT/floors.json"
echo "  per-floor grids      : $OUT/floors/<id>/grid.pgm + grid.yaml (nav2 map_server)"
echo "  report               : $OUT/report.html, $OUT/report.json, $OUT/eval.json"
