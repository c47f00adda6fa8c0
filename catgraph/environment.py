"""What produced a result: the package's and its dependencies' versions, and the machine.

A result file names its method and parameters; to give the same numbers again, a run also
needs the same code and, for the last bits, the same compile target. The numba kernels
that sum with ``fastmath`` (the difference rows' float32 sums, the sequence matcher's
moments, parts of the grid filter) are vectorised as the compiler's model of the target
CPU chooses, so their last bits follow the CPU numba compiles for: the host's, or the one
``NUMBA_CPU_NAME`` names (``docs/evaluation.md``, "Reproducing the tables on another
machine"). :func:`environment` is what every result file records under ``"environment"``
(:func:`catgraph.experiment.payload`) and what ``catgraph info`` prints.

Versions are read from the installed packages' metadata, so nothing is imported to learn
them; only the compile target asks llvmlite, which numba has loaded wherever a method ran.
"""

from __future__ import annotations

import os
import platform
from functools import lru_cache
from importlib import metadata
from pathlib import Path

__all__ = ["DECISIVE", "DEPENDENCIES", "environment", "processor", "compile_target"]

#: The packages whose versions a result records (``None`` where one is not installed:
#: ``av`` reads videos, ``distributed`` runs sweeps and maps on Dask, both optional).
DEPENDENCIES = ("numpy", "scipy", "numba", "llvmlite", "networkx", "filterpy", "matplotlib", "av", "distributed")

#: The entries of :func:`environment` that decide a run's numbers: the code's versions, and
#: the CPU the kernels were compiled for (the last bits of their sums).
DECISIVE = ("catgraph", "numpy", "scipy", "numba", "llvmlite", "compiled_for")


def processor() -> str:
    """The processor's model name (``/proc/cpuinfo``; elsewhere ``platform.processor()``, or
    the architecture). A virtual machine may shorten it to the vendor and family."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return " ".join(line.split(":", 1)[1].split())
    except OSError:
        pass
    return platform.processor() or platform.machine()


def compile_target() -> str | None:
    """The CPU numba compiles the kernels for: ``NUMBA_CPU_NAME`` where set, else llvmlite's
    name for this processor (``znver4``, ``rocketlake`` …); ``None`` without llvmlite."""
    if os.environ.get("NUMBA_CPU_NAME"):
        return os.environ["NUMBA_CPU_NAME"]
    try:
        import llvmlite.binding as llvm

        return llvm.get_host_cpu_name()
    except (ImportError, OSError):  # not installed, or its library does not load
        return None


def _version(package: str) -> str | None:
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return None


def environment() -> dict:
    """The versions and the machine, JSON-ready (a new dict each call; read once per process)::

        {"catgraph": "0.2.0", "python": "3.11.7", "numpy": "2.4.6", ..., "av": None,
         "platform": "Linux-…-x86_64-…", "processor": "AMD EPYC", "cores": 2,
         "compiled_for": "znver4"}
    """
    return dict(_environment())


@lru_cache(maxsize=1)
def _environment() -> dict:
    from . import __version__

    out: dict = {"catgraph": __version__, "python": platform.python_version()}
    out.update({name: _version(name) for name in DEPENDENCIES})
    out.update(platform=platform.platform(), processor=processor(), cores=os.cpu_count(),
               compiled_for=compile_target())
    return out
