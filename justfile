# Recipes by name; each is a plain command you can also run without `just`.

# Cook the bundled 4-frame smoke sequence into smoke.vpak.
run:
    scripts/run.sh

# The whole test suite (installs the Debian packages the tests need).
test:
    scripts/test.sh

# Benchmarks against peers in the same run: read throughput against OpenVDB,
# tree sizes against the thesis layout, cook throughput against nanovdb_convert, memory.
bench:
    /usr/bin/python3 scripts/bench_read.py
    /usr/bin/python3 scripts/bench_cook.py

# Regenerate fixtures/ with OpenVDB itself (byte-identical output).
fixtures:
    /usr/bin/python3 fixtures/make_fixtures.py

# Regenerate the blosc test vectors with libblosc.
blosc-vectors:
    /usr/bin/python3 scripts/make_blosc_vectors.py
