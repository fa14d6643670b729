"""Shared helpers of the benchmark scripts (run as `python benchmarks/bench_*.py`)."""
from __future__ import annotations

import resource
import sys
import time


def _fmt(x, nd=2) -> str:
    if x is None:
        return "-"
    if isinstance(x, bool):
        return "yes" if x else "NO"
    if isinstance(x, float):
        if x != 0 and abs(x) < 10 ** -nd:
            return f"{x:.1e}"
        return f"{x:.{nd}f}"
    return str(x)


def format_table(headers, rows) -> str:
    """Plain fixed-width table: first column left-aligned, the rest right-aligned."""
    cells = [[_fmt(c) for c in r] for r in rows]
    widths = [max(len(h), *(len(r[i]) for r in cells)) if cells else len(h)
              for i, h in enumerate(headers)]

    def line(r):
        return "  ".join(c.ljust(w) if i == 0 else c.rjust(w)
                         for i, (c, w) in enumerate(zip(r, widths)))
    return "\n".join([line(headers), line(["-" * w for w in widths]), *map(line, cells)])


def _timed(fn, *args, **kwargs):
    """``(fn(*args, **kwargs), wall seconds)``."""
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t0


def _peak_rss_mb() -> dict:
    """Peak resident memory (MiB) of this process and of its largest waited-for child."""
    scale = 1024 if sys.platform != "darwin" else 1024 * 1024  # ru_maxrss: KiB on Linux
    return {"self": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / scale,
            "children": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / scale}
