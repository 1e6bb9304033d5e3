"""Timing benchmarks of odolab commands against reference tools."""
