"""Benchmarks: accuracy and speed targets, run by hand or in CI's benchmark job, never as timed unit tests."""
