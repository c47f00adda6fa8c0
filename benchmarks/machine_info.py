"""The machine a benchmark ran on, named alike by every benchmark that times something.

A timing is the machine's: the same code measured 12.3 ms on one 2-core machine and 8.7 ms on
another whose memory reads faster (``benchmarks/results/live_notes.md``). ``x86_64`` does not
tell them apart, so the tables name the processor (``/proc/cpuinfo``'s model name, which a
virtual machine may shorten to its vendor and family) and the CPU that numba compiles for
(llvmlite's name for it, ``znver4``, ``rocketlake`` …, or ``NUMBA_CPU_NAME``).
"""

from __future__ import annotations

import os
import platform
from pathlib import Path


def cpu_model() -> str:
    """The processor's model name (``/proc/cpuinfo``; elsewhere ``platform.processor()`` or
    the architecture)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return " ".join(line.split(":", 1)[1].split())
    except OSError:
        pass
    return platform.processor() or platform.machine()


def compiled_for() -> str | None:
    """The CPU numba compiles for: ``NUMBA_CPU_NAME`` where set, else llvmlite's name for this
    processor; ``None`` where llvmlite is absent.

    The kernels that sum with ``fastmath`` are vectorised as the compiler's model of that CPU
    chooses, so their last bits (and a table's cells) follow it: a table compiled for one CPU
    reproduces float for float on another processor with ``NUMBA_CPU_NAME`` set to it
    (``docs/evaluation.md``, "Reproducing the tables on another machine").
    """
    if os.environ.get("NUMBA_CPU_NAME"):
        return os.environ["NUMBA_CPU_NAME"]
    try:
        import llvmlite.binding as llvm
    except ImportError:
        return None
    return llvm.get_host_cpu_name()


def describe_machine() -> str:
    """``"AMD EPYC (numba compiles for znver4), x86_64, 2 cores, Python 3.11.7"``."""
    target = compiled_for()
    chosen = " by NUMBA_CPU_NAME" if os.environ.get("NUMBA_CPU_NAME") else ""
    cpu = cpu_model() + (f" (numba compiles for {target}{chosen})" if target else "")
    return f"{cpu}, {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"
