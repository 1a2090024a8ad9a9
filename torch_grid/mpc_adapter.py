"""The former path of torch_grid.optim.mpc_adapter, kept for one release (CHANGELOG.md)."""
from __future__ import annotations

import warnings

from .optim.mpc_adapter import MPCDynamics, chart_maps

__all__ = ["MPCDynamics", "chart_maps"]

warnings.warn("torch_grid.mpc_adapter is now torch_grid.optim.mpc_adapter; the old path goes in 0.3",
              DeprecationWarning, stacklevel=2)
