"""Evaluation and benchmarks of the front-end: the paper's tables, repeatability, timings."""
