"""Runs of the whole pipeline on simulated scenarios and logs, sweeps, drift analysis and timings."""
