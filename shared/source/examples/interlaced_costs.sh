#!/usr/bin/env bash
# What each way of reading interlaced frames costs (BENCHMARKS.md, "Interlaced HD"): renders a woven colon
# flight (`synth --interlaced`: 2·FRAMES fields at 60 Hz) and tracks it four ways — the progressive twin, the
# woven frames as they are, --interlaced top-field, --interlaced bob — printing each run's ATE against the top
# fields' truth and its map error. Usage: interlaced_costs.sh OUT [SPEED_MM_S] [FRAMES] [WIDTH HEIGHT]
set -euo pipefail
out=${1:?usage: interlaced_costs.sh OUT [SPEED_MM_S] [FRAMES] [WIDTH HEIGHT]}
speed=${2:-20}; frames=${3:-40}; width=${4:-640}; height=${5:-480}
bin="$(cd "$(dirname "$0")/../../.." && pwd)/target/release/bdis-slam"
[ -x "$bin" ] || { echo "build first: cargo build --release" >&2; exit 1; }
focal=$(python3 -c "print(520 * $width / 640)")
"$bin" synth --interlaced --frames "$frames" --speed "$speed" --width "$width" --height "$height" --focal "$focal" --out "$out/render"
for way in progressive weave top-field bob; do
  case $way in
    progressive) seq="$out/render/progressive"; extra=() ;;
    weave) seq="$out/render/interlaced"; extra=() ;;
    *) seq="$out/render/interlaced"; extra=(--interlaced "$way") ;;
  esac
  run="$out/run-$way"
  rm -rf "$run"
  "$bin" run --track --sequence "$seq" --settings "$seq/settings.yaml" "${extra[@]}" --out "$run" > "$run.log" 2>&1
  ate=$("$bin" eval traj --gt "$out/render/progressive/gt/poses.tum" --est "$run/trajectory.tum" | grep '^ATE')
  map=$("$bin" eval map --json --mesh "$out/render/progressive/gt/mesh.ply" --map "$run/map.ply" \
        --align-est "$run/keyframes.tum" --align-gt "$out/render/progressive/gt/poses.tum" \
        | python3 -c "import json, sys; print(json.load(sys.stdin)['inliers']['mean'])")
  echo "$way: $ate; map mean $map mm"
done
