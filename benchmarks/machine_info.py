"""The machine a benchmark ran on, named alike by every benchmark that times something.

A timing is the machine's: the same code measured 12.3 ms on one 2-core machine and 8.7 ms on
another whose memory reads faster (``benchmarks/results/live_notes.md``). ``x86_64`` does not
tell them apart, so the tables name the processor (``/proc/cpuinfo``'s model name, which a
virtual machine may shorten to its vendor and family) and the CPU that numba compiles for
(llvmlite's host CPU name: ``znver4``, ``rocketlake`` …).
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
    """The CPU numba compiles for (llvmlite's host CPU name); ``None`` where llvmlite is absent."""
    try:
        import llvmlite.binding as llvm
    except ImportError:
        return None
    return llvm.get_host_cpu_name()


def describe_machine() -> str:
    """``"AMD EPYC (llvmlite znver4), x86_64, 2 cores, Python 3.11.7"``."""
    target = compiled_for()
    cpu = cpu_model() + (f" (llvmlite {target})" if target else "")
    return f"{cpu}, {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"
