"""Fast parser of event text lines ``t x y p`` (compiled with numba when it is installed).

Timestamps are parsed as decimal text, not through a float: the integer part and the first
``frac_digits`` fraction digits give an exact integer (the next digit rounds half up), so
absolute Unix times in seconds with nanosecond digits become exact microseconds.
"""

from __future__ import annotations

import numpy as np

try:  # numba is optional: without it the same function runs as (slow) Python
    from numba import njit
except ImportError:  # pragma: no cover - exercised only without numba

    def njit(*args, **kwargs):  # type: ignore[no-redef]
        if args and callable(args[0]):
            return args[0]
        return lambda f: f

    HAVE_NUMBA = False
else:
    HAVE_NUMBA = True

# error codes returned by parse_block
OK = 0
BAD_TIME = 1
BAD_INT = 2
MISSING_FIELD = 3
EXTRA_FIELD = 4
OUT_OF_RANGE = 5
NO_ROOM = 6
ERROR_NAMES = {
    NO_ROOM: "more lines than the parser's buffers hold (internal limit)",
    OUT_OF_RANGE: "integer out of range (x, y need 31 bits, p 7 bits)",
    BAD_TIME: "cannot read the timestamp",
    BAD_INT: "cannot read an integer column",
    MISSING_FIELD: "fewer than 4 columns (t x y p)",
    EXTRA_FIELD: "more than 4 columns (t x y p)",
}


@njit(cache=True, nogil=True, inline="always")
def _digits(buf, i, n):  # pragma: no cover
    """The decimal digits of ``buf`` from ``i``: ``(index after them, value, number of digits)``."""
    v = np.int64(0)
    d = 0
    while i < n and buf[i] >= 48 and buf[i] <= 57:
        v = v * 10 + (buf[i] - 48)
        i += 1
        d += 1
    return i, v, d


# Over 80 lines on purpose: a numba-compiled single-pass byte parser whose states (skip line,
# number, field, error) share one cursor; split, it would pass the cursor through every call.
@njit(cache=True, nogil=True)
def parse_block(
    buf, t_out, x_out, y_out, p_out, skip_at, skip_count, int_mult, frac_digits
):  # pragma: no cover
    """Parse lines of ``buf`` (uint8) into ``t_out`` (int64), ``x_out``/``y_out`` (int32), ``p_out`` (int8).

    The event arrays need one slot per event line; ``len(buf) // 8 + 1`` always suffices (a
    shortest event line, "0 0 0 0\n", has 8 bytes; the last line may lack its newline).
    Lines that are empty or start with ``#`` or ``%`` are skipped and recorded as runs (to map
    events back to line numbers): run ``r`` is ``skip_count[r]`` skipped lines met when
    ``skip_at[r]`` events had been read. Runs are separated by events, so ``len(buf) // 8 + 2``
    slots suffice for them too; every write is bounds-checked all the same (``NO_ROOM``).
    Returns ``(n_events, n_lines, n_runs, error_code, error_line)`` (0-based line in the block).
    """
    n = len(buf)
    i = 0
    ne = 0
    nl = 0
    ns = 0
    while i < n:
        # leading blanks
        while i < n and (buf[i] == 32 or buf[i] == 9 or buf[i] == 13):
            i += 1
        if i >= n:
            break
        c = buf[i]
        if c == 10 or c == 35 or c == 37:  # empty line, '#', '%'
            while i < n and buf[i] != 10:
                i += 1
            i += 1
            if ns > 0 and skip_at[ns - 1] == ne:
                skip_count[ns - 1] += 1
            else:
                if ns >= len(skip_at):
                    return ne, nl, ns, NO_ROOM, nl
                skip_at[ns] = ne
                skip_count[ns] = 1
                ns += 1
            nl += 1
            continue
        if ne >= len(t_out):
            return ne, nl, ns, NO_ROOM, nl
        # timestamp: digits [. digits]
        i, ip, nd = _digits(buf, i, n)
        fp = np.int64(0)
        nf = 0
        rnd = 0
        if i < n and buf[i] == 46:
            i += 1
            while i < n and buf[i] >= 48 and buf[i] <= 57:
                if nf < frac_digits:
                    fp = fp * 10 + (buf[i] - 48)
                elif nf == frac_digits:
                    rnd = 1 if buf[i] >= 53 else 0
                nf += 1
                nd += 1
                i += 1
        if nd == 0:
            return ne, nl, ns, BAD_TIME, nl
        while nf < frac_digits:
            fp = fp * 10
            nf += 1
        t_out[ne] = ip * int_mult + fp + rnd
        # three integer columns
        for col in range(3):
            if i >= n or not (buf[i] == 32 or buf[i] == 9 or buf[i] == 44):
                if i < n and (buf[i] == 10 or buf[i] == 13):
                    return ne, nl, ns, MISSING_FIELD, nl
                return ne, nl, ns, BAD_TIME if col == 0 else BAD_INT, nl
            while i < n and (buf[i] == 32 or buf[i] == 9 or buf[i] == 44):
                i += 1
            neg = False
            if i < n and (buf[i] == 45 or buf[i] == 43):
                neg = buf[i] == 45
                i += 1
            i, v, d = _digits(buf, i, n)
            if d == 0:
                if i >= n or buf[i] == 10 or buf[i] == 13:
                    return ne, nl, ns, MISSING_FIELD, nl
                return ne, nl, ns, BAD_INT, nl
            if d > 10 or v > 2147483647 or (col == 2 and v > 127):
                return ne, nl, ns, OUT_OF_RANGE, nl
            if neg:
                v = -v
            if col == 0:
                x_out[ne] = v
            elif col == 1:
                y_out[ne] = v
            else:
                p_out[ne] = v
        while i < n and (buf[i] == 32 or buf[i] == 9 or buf[i] == 13):
            i += 1
        if i < n and buf[i] != 10:
            return ne, nl, ns, EXTRA_FIELD, nl
        i += 1
        ne += 1
        nl += 1
    return ne, nl, ns, OK, -1
