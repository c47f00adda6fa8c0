"""A benchmark process's own memory, read from ``/proc/self/status`` (Linux).

The peak is ``VmHWM``, never ``getrusage``'s ``ru_maxrss``: on Linux that keeps, across
``exec``, the peak of the process the child was forked from, so a case started from a
benchmark that holds a large reference (or a Dask worker spawned from it) reports the
parent's memory as its own. Measured: a Dask worker spawned from a process holding 800 MB
reported ``ru_maxrss`` 822 MB against its own ``VmHWM`` of 62 MB.
"""

from __future__ import annotations


def status_mb(key: str) -> float:
    """``VmRSS`` (now), ``VmHWM`` (peak since the process started or its last
    :func:`reset_peak`), ``RssAnon`` … of this process in MiB (``/proc``'s kB / 1024, which the
    tables print as MB; NaN where not reported)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(key + ":"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return float("nan")


def peak_rss_mb() -> float:
    """This process's own peak RSS in MiB (``VmHWM``)."""
    return status_mb("VmHWM")


def reset_peak() -> bool:
    """Start a new peak-RSS window (Linux: ``/proc/self/clear_refs`` ← 5 resets ``VmHWM``)."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False
