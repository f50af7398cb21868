"""Batch jobs built on the mfmap library: regression over many logs, benchmarks."""
