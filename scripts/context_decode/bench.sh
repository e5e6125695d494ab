#!/bin/bash
# How fast a static-context rANS decoder restores quantised bricks, against zstd's
# decoder on the same bricks (issue 24; docs/benchmarks.md). Needs
# bench-out/fog_256.vdb (scripts/make_bench_volume.py bench-out/fog_256.vdb --size 256)
# and ../shared/vdb-samples.
#     bash scripts/context_decode/bench.sh      (RUNS=7 by default)
set -e
cd "$(dirname "$0")"
ROOT=$(cd ../.. && pwd)
S=$ROOT/../shared/vdb-samples
mkdir -p data
ROWS=(
  "fog_e0.01|$ROOT/bench-out/fog_256.vdb|0.01|density"
  "fog_e0.001|$ROOT/bench-out/fog_256.vdb|0.001|density"
  "smoke_e0.01|$S/arnold-usd/smoke.vdb|0.01|density"
  "flames_e0.01|$S/vfx-toolkit-embergen/embergen_fire_a_50.vdb|0.01|flames"
)
cargo build --release -q
for row in "${ROWS[@]}"; do
  IFS='|' read -r tag vdb e grid <<< "$row"
  [ -f data/$tag.bin ] || /usr/bin/python3 export_bricks.py "$vdb" "$e" "$grid" data/$tag.bin --ideal
  ./target/release/context_decode data/$tag.bin --runs ${RUNS:-7} --zst data/$tag.zst
  # Every voxel coded (no masks): the vector decoders only.
  ./target/release/context_decode data/$tag.bin --runs ${RUNS:-7} --only x --no-masks | grep -E 'no-masks|AVX'
  /usr/bin/python3 cli_zstd.py data/$tag.zst ${RUNS:-7}
done
