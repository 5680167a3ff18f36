#!/usr/bin/env bash
# Makes the sources decode_cost.rs measures from real footage (../shared/data/kitti-a, 51 stereo frames), scaled
# to 640×480 and 1920×1080: PNG pairs, a stacked H.264 mp4 as a recorder writes it (CRF 18, 4:2:0), the same
# lossless, a side-by-side MJPEG AVI (read in process, without ffmpeg), a stacked Y4M (4:2:0, read in process)
# and two FFV1 files; then measures them.
# Usage: shared/source/examples/decode_cost.sh [WORK_DIR]
set -euo pipefail
cd "$(dirname "$0")/../../.."
data=../shared/data/kitti-a
work=${1:-$(mktemp -d)}
sources=()
for size in 640x480 1920x1080; do
  w=${size%x*}; h=${size#*x}; d=$work/$size
  mkdir -p "$d/seq/left" "$d/seq/right"
  for side in left right; do
    ffmpeg -v error -y -i "$data/$side/%06d.png" -vf "scale=$w:$h" -start_number 1 "$d/seq/$side/%d.png"
  done
  in=(-framerate 10 -i "$d/seq/left/%d.png" -framerate 10 -i "$d/seq/right/%d.png")
  ffmpeg -v error -y "${in[@]}" -filter_complex vstack -c:v libx264 -crf 18 -pix_fmt yuv420p "$d/stacked.mp4"
  ffmpeg -v error -y "${in[@]}" -filter_complex vstack -c:v libx264 -qp 0 -pix_fmt yuv444p "$d/stacked-lossless.mp4"
  ffmpeg -v error -y "${in[@]}" -filter_complex hstack -c:v mjpeg -q:v 2 -pix_fmt yuvj422p "$d/side-by-side.avi"
  ffmpeg -v error -y "${in[@]}" -filter_complex vstack -pix_fmt yuv420p "$d/stacked.y4m"
  for side in left right; do
    ffmpeg -v error -y -framerate 10 -i "$d/seq/$side/%d.png" -c:v ffv1 -pix_fmt bgr0 "$d/$side.mkv"
  done
  sources+=("$d/seq" "video:top-bottom:$d/stacked.mp4" "video:top-bottom:$d/stacked-lossless.mp4"
            "video:side-by-side:$d/side-by-side.avi" "video:top-bottom:$d/stacked.y4m"
            "video:two-files:$d/left.mkv,$d/right.mkv")
done
cargo run -q --release -j2 -p bdis-source --example decode_cost -- "${sources[@]}"
# The same, rectified as it is read (acquisition's --calibration): the sample rig of tests/calibrations scaled to
# each size (its 8-coefficient distortion and 0.74° turn; the footage is not from it: this measures cost only).
for size in 640x480 1920x1080; do
  w=${size%x*}; h=${size#*x}; d=$work/$size
  python3 - "$w" "$h" "$d/calib.yaml" <<'PY'
import re, sys
w, h, out = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
text = open("tests/calibrations/scared/endoscope_calibration.yaml").read()
def scale(m):
    v = [float(x) for x in m.group(2).split(",")]
    v[0] *= w / 1280; v[2] *= w / 1280; v[4] *= h / 1024; v[5] *= h / 1024
    return m.group(1) + ", ".join(repr(x) for x in v) + " ]"
text = re.sub(r"(M[12]: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: \[ )([^\]]*) \]", scale, text)
text = text.replace("width: 1280", f"width: {w}").replace("height: 1024", f"height: {h}")
open(out, "w").write(text)
PY
  cargo run -q --release -j2 -p bdis-source --example decode_cost -- --calibration "$d/calib.yaml" \
    "$d/seq" "video:top-bottom:$d/stacked.mp4" "video:side-by-side:$d/side-by-side.avi"
done
