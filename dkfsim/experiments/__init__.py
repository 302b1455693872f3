"""Experiments over many runs: Monte Carlo, parameter sweeps, the maximum allowable delay."""
