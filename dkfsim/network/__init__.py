"""The network: SimPy links with per-packet latency, loss and faults, shared by every estimator."""
