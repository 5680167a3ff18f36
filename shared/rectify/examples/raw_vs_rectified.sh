#!/usr/bin/env bash
# What rectification costs tracking (BENCHMARKS.md, "Tracking after rectification"; issue #18): for each texture
# seed, renders the colon flight three times from the same path — rectified, through the `mild` raw rig and through
# the `strong` one — rectifies the raw renders with `bdis-slam rectify`, and tracks every variant offline
# (`track_sequence`) from several start frames. A start frame is a view of the folder from that frame on (links),
# so the three variants of one (seed, start) see the same motion: their ATE ratio is a paired comparison.
# Prints one line per run and writes OUT/ate.csv; summarise with raw_vs_rectified.py OUT/ate.csv.
# SYNTH_ARGS: more `bdis-slam synth` arguments for every render (e.g. "--optics-blur-px 0.5").
# Usage: raw_vs_rectified.sh OUT [WIDTH HEIGHT FRAMES "SEEDS" STARTS "SYNTH_ARGS"]
set -euo pipefail
out=${1:?usage: raw_vs_rectified.sh OUT [WIDTH HEIGHT FRAMES "SEEDS" STARTS "SYNTH_ARGS"]}
width=${2:-320}; height=${3:-240}; frames=${4:-120}; seeds=${5:-"2026 7 11 12"}; starts=${6:-8}
read -r -a synth_args <<< "${7:-}"
root="$(cd "$(dirname "$0")/../../.." && pwd)"
bin="$root/target/release/bdis-slam"; track="$root/target/release/examples/track_sequence"
[ -x "$bin" ] && [ -x "$track" ] || { echo "build first: cargo build --release; cargo build --release -p bdis-track --example track_sequence" >&2; exit 1; }
focal=$(python3 -c "print(520 * $width / 640)")
mkdir -p "$out"
csv="$out/ate.csv"
[ -f "$csv" ] || echo "seed,start,variant,ate_mm" > "$csv"
for seed in $seeds; do
  for variant in rectified mild strong; do
    dir="$out/s$seed/$variant"
    [ -d "$dir/left" ] && continue
    raw=(); [ "$variant" = rectified ] || raw=(--raw "$variant")
    "$bin" synth --width "$width" --height "$height" --focal "$focal" --frames "$frames" --seed "$seed" "${raw[@]}" "${synth_args[@]}" \
      --out "$dir.render" > /dev/null
    if [ "$variant" = rectified ]; then mv "$dir.render" "$dir"; else
      "$bin" rectify --settings "$dir.render/calib.yaml" --sequence "$dir.render" --out "$dir" > /dev/null
      mv "$dir.render/gt" "$dir/gt"; rm -rf "$dir.render"
    fi
  done
  for start in $(seq 0 $((starts - 1))); do
    for variant in rectified mild strong; do
      grep -q "^$seed,$start,$variant," "$csv" && continue
      dir="$out/s$seed/$variant"; view="$out/view"
      rm -rf "$view"; mkdir -p "$view/left" "$view/right"
      for side in left right; do
        ls "$dir/$side" | sort -n | tail -n +$((start + 1)) | while read -r f; do ln -s "$dir/$side/$f" "$view/$side/$f"; done
      done
      tail -n +$((start + 1)) "$dir/times.txt" > "$view/times.txt"
      "$track" "$view" "$out/est.tum" --settings "$dir/settings.yaml" 2> /dev/null
      ate=$("$bin" eval traj --json --gt "$out/s$seed/rectified/gt/poses.tum" --est "$out/est.tum" \
            | python3 -c "import json, sys; d = json.load(sys.stdin); print(d['ate']['translation']['rmse'])")
      echo "$seed,$start,$variant,$ate" | tee -a "$csv"
    done
  done
done
