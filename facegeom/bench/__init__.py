"""Benchmark protocols: seeded, run by one command, writing CSV + a plot + a table."""
