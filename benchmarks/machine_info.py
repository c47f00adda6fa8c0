"""The machine a benchmark ran on, named alike by every benchmark that times something.

A timing is the machine's: the same code measured 12.3 ms on one 2-core machine and 8.7 ms on
another whose memory reads faster (``benchmarks/results/live_notes.md``). ``x86_64`` does not
tell them apart, so the tables name the processor and the CPU numba compiles for, as a result
file records them (:mod:`catgraph.environment`; that CPU also decides the last bits of the
kernels that sum with ``fastmath``, ``docs/evaluation.md``).
"""

from __future__ import annotations

import os
import platform


def describe_machine() -> str:
    """``"AMD EPYC (numba compiles for znver4), x86_64, 2 cores, Python 3.11.7"``."""
    from catgraph.environment import compile_target, processor  # here: a live benchmark's process imports it late

    target = compile_target()
    chosen = " by NUMBA_CPU_NAME" if os.environ.get("NUMBA_CPU_NAME") else ""
    cpu = processor() + (f" (numba compiles for {target}{chosen})" if target else "")
    return f"{cpu}, {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"
