"""The virtual robot: plant physics, effects, drive emulation (and, later, protocol servers)."""

import os

# One BLAS thread. The matrices here are small (≤ 8000×9) and the machine may have two cores
# shared with a realtime loop: OpenBLAS worker threads spin, steal the loop's core and made a
# 8000×9 least-squares solve 10× slower under load. Set before numpy is first imported.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

__version__ = "0.1.0"
