"""Batch runs: one command over many sessions or sequences, on a process pool or Ray."""
