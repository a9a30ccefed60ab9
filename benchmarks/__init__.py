"""Benchmarks run on demand: `python -m benchmarks` lists them, `python -m benchmarks NAME` runs one (`all`: every
one); never collected by pytest."""
