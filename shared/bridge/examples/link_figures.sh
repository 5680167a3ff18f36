#!/usr/bin/env bash
# The bridge's figures (BENCHMARKS.md, "The bridge"): a sequence run on one host, then over two iceoryx2 systems
# joined only by the bridge's Zenoh link on loopback, both paced on-demand:30hz; prints capture → map on each, the
# bridge's CPU and the link's delay, and checks host B's map.ply is byte for byte the single host's.
#   usage: link_figures.sh SEQUENCE OUT [map|stereo]    (SEQUENCE: e.g. `bdis-slam synth --scene colon --frames 300
#          --width 320 --height 240 --focal 260 --out c300`; run from the repository after `cargo build --release`)
set -u
REPO=$(cd "$(dirname "$0")/../../.." && pwd)
B=$REPO/target/release/bdis-slam
SEQ=$(cd "$1" && pwd); M=$2; P=${3:-map}
rm -rf "$M"; mkdir -p "$M"
if [ "$P" = map ]; then A=two-hosts-a; BB=two-hosts-b; else A=two-hosts-stereo-a; BB=two-hosts-stereo-b; fi
sed 's/"on-demand"/"on-demand:30hz"/' "$REPO/launch/$A.toml" > "$M/a.toml"
"$B" run --track --sequence "$SEQ" --settings "$SEQ/settings.yaml" --pacing on-demand:30hz --out "$M/single" > "$M/single.log" 2>&1
BDIS_SETTINGS=$SEQ/settings.yaml BDIS_BRIDGE_LISTEN=127.0.0.1:18961 "$B" run "$REPO/launch/$BB.toml" --ipc-prefix pB_ --out "$M/runB" > "$M/b.log" 2>&1 &
sleep 1
BDIS_SEQUENCE=$SEQ BDIS_SETTINGS=$SEQ/settings.yaml BDIS_BRIDGE_PEER=127.0.0.1:18961 \
  "$B" run "$M/a.toml" --ipc-prefix pA_ --out "$M/runA" > "$M/a.log" 2>&1
wait
cmp "$M/runB/map.ply" "$M/single/map.ply" && echo "map.ply identical"
python3 - "$M" <<'PY'
import json, sys
M = sys.argv[1]
def run(r): return json.load(open(f"{M}/{r}/latency.json"))
for r in ("single", "runB"):
    for e in run(r)["end_to_end"]:
        if e["path"] == "capture → map":
            l = e["latency_us"]
            print(f"{r}: capture → map p50/p90/p99 {l['p50']/1e3:.2f} / {l['p90']/1e3:.2f} / {l['p99']/1e3:.2f} ms")
for r in ("runA", "runB"):
    for p in run(r)["processes"]:
        if p["name"] == "bridge":
            print(f"{r}: bridge CPU {p['cpu_time_s']:.3f} s")
PY
grep -h "receiver done" "$M/runB/logs/bridge.log" | sed 's/.*the sender/the sender/'
