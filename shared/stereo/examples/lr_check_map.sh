#!/usr/bin/env bash
# The dense map through the processes with each stereo variant on one rendered sequence: BDIS and plain DIS,
# each with its left–right check (the default) and without it (lr_check=0), scored against the renderer's mesh.
# The tracker's poses are the same in every run (the dense side does not feed back), so only the stereo differs.
#
#   shared/stereo/examples/lr_check_map.sh SEQ OUT      # SEQ: a `bdis-slam synth` folder (gt/mesh.ply)
#
# Prints one line per variant (points, outliers > 5 mm, mean / median distance, coverage) and writes OUT/maps.csv.
set -euo pipefail
seq=${1:?sequence folder}; out=${2:?output folder}
bin=${BDIS_SLAM:-target/release/bdis-slam}
mkdir -p "$out"
"$bin" run --track --sequence "$seq" --settings "$seq/settings.yaml" --out "$out/bdis" > "$out/bdis.log" 2>&1
echo "variant,points,outliers,mean_mm,median_mm,coverage" > "$out/maps.csv"
score() {
  "$bin" eval map --mesh "$seq/gt/mesh.ply" --map "$out/$1/map.ply" --align-est "$out/$1/keyframes.tum" \
    --align-gt "$seq/gt/poses.tum" --json |
    python3 -c 'import json,sys; s=json.load(sys.stdin); print(",".join(map(str,[sys.argv[1], s["points"], s["outliers"], round(s["inliers"]["mean"],4), round(s["inliers"]["median"],4), round(s["coverage"],4)])))' "$1" |
    tee -a "$out/maps.csv"
}
score bdis
# The same launch file with the stereo service's arguments extended (a later flag wins).
for variant in "bdis-unchecked:--param lr_check=0" "dis:--algorithm dis" "dis-unchecked:--algorithm dis --param lr_check=0"; do
  name=${variant%%:*}; extra=${variant#*:}
  python3 - "$out/bdis/launch.toml" "$out/$name.toml" $extra <<'PY'
import sys
src, dst, extra = sys.argv[1], sys.argv[2], sys.argv[3:]
text = open(src).read()
marker = '"--input",\n    "keyframes",\n'
assert marker in text, "the stereo service's arguments are not where expected in " + src
open(dst, "w").write(text.replace(marker, marker + "".join(f'    "{a}",\n' for a in extra), 1))
PY
  "$bin" run "$out/$name.toml" --out "$out/$name" > "$out/$name.log" 2>&1
  score "$name"
done
