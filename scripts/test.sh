#!/usr/bin/env bash
# The whole test suite, on a fresh Debian machine with only Rust installed.
# Installs the Debian packages the tests need (OpenVDB's reference tools,
# used as the oracle in differential tests, Mesa's Vulkan drivers for the
# GPU tests, and for `bake`'s reports and docs: junitparser to read the JUnit
# XML back, Chromium to load the HTML report, make for docs/ci.md's Makefile,
# g++ for NVIDIA's FLIP, which the nv-flip crate compiles from C++, and for
# `view`'s window test an X server, xdotool and ImageMagick's import, and
# GNU time, whose peak-memory figure the segments tests compare)
# when they are missing, then runs every test in the workspace.
set -euo pipefail
cd "$(dirname "$0")/.."

. scripts/debian-packages.sh
need python3-openvdb python3-numpy python3-pil python3-xxhash python3-zstandard libopenvdb-tools libnanovdb-tools libblosc1 mesa-vulkan-drivers libvulkan1 python3-junitparser chromium make g++ xvfb xauth xdotool imagemagick time

# Mesa's Vulkan loader wants a runtime directory; the GPU tests run on its
# CPU driver (lavapipe) when there is no GPU.
if [ -z "${XDG_RUNTIME_DIR:-}" ]; then
    XDG_RUNTIME_DIR="$(mktemp -d)"
    trap 'rm -rf "$XDG_RUNTIME_DIR"' EXIT
    export XDG_RUNTIME_DIR
fi

cargo test --workspace --locked "$@"
