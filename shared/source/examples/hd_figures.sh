#!/usr/bin/env bash
# HD in real time (BENCHMARKS.md, "HD in real time"): the same flight rendered at 640×480, 1280×720 and
# 1920×1080 with one field of view (f = 520 · width / 640), each made a top-bottom Y4M (raw frames, as a console
# feeds them) and run through the processes with launch/hd-2cores.toml at `on-demand:30hz`; prints each size's
# latency rows, tracking CPU, ATE relative to the path and map error. Renders and Y4Ms already in OUT are reused
# (a 300-frame 1080p colon takes ~50 min on 2 cores). Usage: hd_figures.sh OUT [FRAMES] [SCENE] [SIZES…];
# SYNTH_ARGS adds to the render's arguments (the abdomen figures: SYNTH_ARGS='--trajectory sweep').
set -euo pipefail
out=${1:?usage: hd_figures.sh OUT [FRAMES] [SCENE] [SIZES…]}
frames=${2:-300}; scene=${3:-colon}
shift $(( $# < 3 ? $# : 3 ))
sizes=("$@"); [ ${#sizes[@]} -gt 0 ] || sizes=(640x480 1280x720 1920x1080)
root="$(cd "$(dirname "$0")/../../.." && pwd)"
bin="$root/target/release/bdis-slam"
[ -x "$bin" ] || { echo "build first: cargo build --release" >&2; exit 1; }
mkdir -p "$out"
for size in "${sizes[@]}"; do
  width=${size%x*}; height=${size#*x}
  focal=$(python3 -c "print(520 * $width / 640)")
  seq="$out/$scene-$size"
  [ -f "$seq/gt/poses.tum" ] || "$bin" synth --scene "$scene" --frames "$frames" --width "$width" --height "$height" \
    --focal "$focal" ${SYNTH_ARGS:-} --out "$seq"
  [ -f "$seq.y4m" ] || ffmpeg -loglevel error -y -framerate 30 -i "$seq/left/%d.png" -framerate 30 -i "$seq/right/%d.png" \
    -filter_complex vstack -pix_fmt yuv420p "$seq.y4m"
  run="$out/run-$scene-$size"
  rm -rf "$run"
  BDIS_SEQUENCE="video:top-bottom:$seq.y4m" BDIS_SETTINGS="$seq/settings.yaml" \
    "$bin" run "$root/launch/hd-2cores.toml" --out "$run" > "$run.log" 2>&1
  echo "== $scene $size"
  sed -n '/^process /,/^$/p' "$run.log" | grep -E "^(acquisition|tracking|stereo|mosaic) "
  grep -E "^capture" "$run.log"
  python3 - "$run/tracking.json" <<'PY'
import json, sys
t = json.load(open(sys.argv[1]))
print(f"tracking CPU per frame p50 {t['frame_cpu_ms_p50']:.2f} ms, p99 {t['frame_cpu_ms_p99']:.2f} ms; "
      f"lost {t['lost']}, uncertain {t['uncertain']}, keyframes {t['keyframes_created']}")
PY
  "$bin" eval traj --gt "$seq/gt/poses.tum" --est "$run/trajectory.tum" | grep '^ATE'
  python3 - "$seq/gt/poses.tum" <<'PY'
import sys
rows = [list(map(float, l.split()[1:4])) for l in open(sys.argv[1]) if l.strip() and not l.startswith('#')]
print(f"path {sum(sum((a - b) ** 2 for a, b in zip(p, q)) ** 0.5 for p, q in zip(rows, rows[1:])):.2f}")
PY
  "$bin" eval map --json --mesh "$seq/gt/mesh.ply" --map "$run/map.ply" --align-est "$run/keyframes.tum" \
    --align-gt "$seq/gt/poses.tum" | python3 -c "import json, sys; m = json.load(sys.stdin); \
print('map: points', m.get('points'), 'inliers mean', m['inliers']['mean'], 'mm')"
done
