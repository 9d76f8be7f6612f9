"""Reproducible benchmarks: experiment files, the method registry, the grid harness and tables."""
