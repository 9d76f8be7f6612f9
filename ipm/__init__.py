"""ipm: inverse procedural modeling with differentiable procedural generators."""

from __future__ import annotations

import logging

from ipm.version import __version__

__all__ = ["__version__", "fit"]

logging.getLogger(__name__).addHandler(logging.NullHandler())


def __getattr__(name: str):
    # ``ipm.fit`` without importing torch and the optimizers at ``import ipm``
    if name == "fit":
        from ipm.fitting import fit

        return fit
    raise AttributeError(f"module 'ipm' has no attribute {name!r}")
