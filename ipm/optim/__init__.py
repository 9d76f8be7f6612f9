"""Optimizers: continuous refinement (Adam, nlopt LD_*), discrete search (memetic, nlopt GN_*,
enumeration), and the fit orchestration. Everything works on a normalized vector ``x`` in [0, 1]^m
(generator parameters, then pose, then camera) plus a dict of discrete values."""
