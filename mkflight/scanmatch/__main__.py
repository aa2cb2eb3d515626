"""``python -m mkflight.scanmatch``: compile (or load) the matcher's kernel, say which runs.

Run once after installing, as the service's user with its ``NUMBA_CACHE_DIR``, so that the
service's first start loads the machine code instead of compiling it (README, "Running it
as a service").
"""

from __future__ import annotations

import sys
import time

from mkflight.scanmatch.kernels import load_kernel


def main() -> int:
    """Load the ``auto`` kernel; one line naming it and the seconds it took."""
    t0 = time.perf_counter()
    kernel = load_kernel("auto")
    sys.stdout.write(
        f"scan matcher kernel: {kernel.name} (ready in {time.perf_counter() - t0:.1f} s)\n"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
