"""A scan's SCIP 2.0 data blocks checked and decoded in one compiled call (numba).

:func:`~mkflight.urg.replies._scan_data` and :func:`~mkflight.urg.codec.decode_array` are
the reference, in numpy: the blocks' sums checked, their characters joined and decoded 6
bits a character (``protocols/scip2.md`` §2.3-2.5). That is some twenty numpy calls a scan,
each paying its overhead on caches the 100 ms between scans have cooled; here it is one
loop over the ~2.1 kB. The outcome is the same in every case -- the same values, or the
same verdict (a bad sum, or malformed) decided in the same order -- and a test holds the
two to it.

Importing this module compiles nothing; the first call compiles it or loads it from
numba's cache (:func:`~mkflight.scanmatch.kernels.warm_up` does that before a flight).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from numba import njit

from mkflight.urg.replies import BLOCKS_MALFORMED, BLOCKS_OK, BLOCKS_SUM

IntArray = npt.NDArray[np.int64]

# (these and the verdicts are frozen into numba's on-disk cache: change them, touch this file)
_LF = 0x0A
_OFFSET = 0x30  # '0' (§2.4)
_FULL = 65  # a full block: 64 characters and its sum (§2.5)


@njit(cache=True, error_model="numpy")
def scan_blocks(lines: bytes, chars: int) -> tuple[int, IntArray]:
    """The verdict on a scan's data blocks and their values (mm) when it is ``BLOCKS_OK``.

    ``lines`` holds the blocks (each its characters then its sum character) joined by LF,
    as they came; ``chars`` is 2 or 3, the characters of a value. As the reference, in
    order: every block but the last must hold 64 characters (the first that does not
    makes the data malformed, after the sums of the blocks before it are checked), the
    last 1 to 64; each block's sum must hold; the characters joined must be a whole
    number of values, each character within ``'0'..'o'``.
    """
    none = np.empty(0, dtype=np.int64)
    n = len(lines)
    if n == 0:
        return BLOCKS_MALFORMED, none  # no block: no value (the reference finds 0 of them)
    last_start = 0
    for i in range(n):
        if lines[i] == _LF:
            last_start = i + 1
    # every block but the last: full, and its sum right
    start = 0
    n_chars = 0
    while start < last_start:
        end = start + _FULL
        if end >= n or lines[end] != _LF:
            return BLOCKS_MALFORMED, none  # a block that is not full before the last
        total = 0
        for i in range(start, end - 1):
            if lines[i] == _LF:
                return BLOCKS_MALFORMED, none  # a shorter block
            total += lines[i]
        if lines[end - 1] == _LF:
            return BLOCKS_MALFORMED, none
        if (total & 0x3F) + _OFFSET != lines[end - 1]:
            return BLOCKS_SUM, none
        n_chars += _FULL - 1
        start = end + 1
    size = n - last_start - 1
    if not 1 <= size <= _FULL - 1:
        return BLOCKS_MALFORMED, none
    total = 0
    for i in range(last_start, n - 1):
        total += lines[i]
    if (total & 0x3F) + _OFFSET != lines[n - 1]:
        return BLOCKS_SUM, none
    n_chars += size
    if n_chars % chars:
        return BLOCKS_MALFORMED, none
    values = np.empty(n_chars // chars, dtype=np.int64)
    value = 0
    k = 0  # characters of the current value so far
    j = 0
    start = 0
    while start < n:
        end = min(start + _FULL, n) - 1  # the block's sum character
        for i in range(start, end):
            digit = lines[i] - _OFFSET
            if not 0 <= digit < 64:
                return BLOCKS_MALFORMED, none
            value = (value << 6) | digit
            k += 1
            if k == chars:
                values[j] = value
                j += 1
                value = 0
                k = 0
        start = end + 2  # past the sum and the LF
    return BLOCKS_OK, values
