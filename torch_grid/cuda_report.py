"""The former path of torch_grid.ops.cuda_report, kept for one release (CHANGELOG.md):
`python -m torch_grid.cuda_report` runs `python -m torch_grid.ops.cuda_report`."""
from __future__ import annotations

import sys
import warnings

from .ops.cuda_report import KernelUsage, main, report

__all__ = ["KernelUsage", "main", "report"]

warnings.warn("torch_grid.cuda_report is now torch_grid.ops.cuda_report; the old path goes in 0.3",
              DeprecationWarning, stacklevel=2)

if __name__ == "__main__":
    sys.exit(main())
