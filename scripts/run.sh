#!/usr/bin/env bash
# The main job on a bundled fixture, on a fresh Debian machine with only Rust
# installed: installs g++ when it is missing (the build compiles NVIDIA's FLIP,
# C++, and links the C++ runtime for the BC7 encoder), then cooks the bundled
# 4-frame smoke sequence into smoke.vpak.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/debian-packages.sh
need g++
cargo run --release -- cook fixtures/smoke_seq -o smoke.vpak --force "$@"
