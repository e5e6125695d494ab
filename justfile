# Recipes by name; each is a plain command you can also run without `just`.

# Describe the bundled smoke fixture (the main job until `cook` exists).
run:
    cargo run --release -- inspect fixtures/fog_blosc.vdb

# The whole test suite (installs the Debian packages the tests need).
test:
    scripts/test.sh

# Read throughput against OpenVDB (pyopenvdb) on a 24M-voxel fog volume.
bench:
    /usr/bin/python3 scripts/bench_read.py

# Regenerate fixtures/ with OpenVDB itself (byte-identical output).
fixtures:
    /usr/bin/python3 fixtures/make_fixtures.py

# Regenerate the blosc test vectors with libblosc.
blosc-vectors:
    /usr/bin/python3 scripts/make_blosc_vectors.py
