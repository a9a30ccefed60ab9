"""Benchmarks run on demand: `python -m benchmarks.bench_<topic>` (never collected by pytest)."""
