"""Benchmarks (``make bench``): every ``bench_*.py`` here has ``main() -> list[Result]``."""
