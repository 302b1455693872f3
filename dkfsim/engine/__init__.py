"""The engine: one run -- the draws, the shared network, the clock, every estimator -- and its result."""
