#!/usr/bin/env bash
# A kill -9 of one side of the bridge 5 s into a run of the map placement (on-demand:30hz): prints the keyframes
# tracked on host A and mapped on host B (BENCHMARKS.md, "The bridge", failures).
#   usage: kill_run.sh SEQUENCE OUT send|receive    (run from the repository after `cargo build --release`)
set -u
REPO=$(cd "$(dirname "$0")/../../.." && pwd)
B=$REPO/target/release/bdis-slam
SEQ=$(cd "$1" && pwd); M=$2; R=$3
rm -rf "$M"; mkdir -p "$M"
sed 's/"on-demand"/"on-demand:30hz"/' "$REPO/launch/two-hosts-a.toml" > "$M/a.toml"
BDIS_BRIDGE_LISTEN=127.0.0.1:18962 "$B" run "$REPO/launch/two-hosts-b.toml" --ipc-prefix kB_ --out "$M/runB" > "$M/b.log" 2>&1 &
sleep 1
BDIS_SEQUENCE=$SEQ BDIS_SETTINGS=$SEQ/settings.yaml BDIS_BRIDGE_PEER=127.0.0.1:18962 \
  "$B" run "$M/a.toml" --ipc-prefix kA_ --out "$M/runA" > "$M/a.log" 2>&1 &
sleep 5
pid=$(pgrep -f "bdis-bridge $R --to 127.0.0.1:18962|bdis-bridge $R --listen 127.0.0.1:18962" | head -1)
kill -9 "$pid" && echo "killed the $R side, pid $pid"
wait
python3 -c "
import json
made = json.load(open('$M/runA/tracking.json'))['keyframes_created']
mapped = json.load(open('$M/runB/mosaic.json'))['keyframes_inserted']
print(f'tracked {made} keyframes on host A, mapped {mapped} on host B')"
