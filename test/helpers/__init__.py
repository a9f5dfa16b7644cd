"""Shared helpers of the test suite (importable as ``helpers`` through pytest's pythonpath)."""
