"""Benchmarks of sqpmpc (not part of the installed package)."""
