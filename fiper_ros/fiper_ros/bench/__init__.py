"""Benchmarks of the fiper-ros suite."""
