"""The package's build: setuptools, plus its compiled kernels cached into the wheel.

``pip install .`` builds a wheel on the machine it installs on. After the sources are
copied into the build folder, the build runs ``catgraph warm-up`` there once, in a fresh
process, so numba compiles every kernel of the live and batch paths and caches the
machine code beside the sources (``catgraph/__pycache__``, numba's in-tree cache); the
wheel carries those files, and the first run after the install loads its kernels instead
of compiling them (measured: ``benchmarks/results/cold_install.md``). numba keys each cached
kernel by the source's content, the numba version and the processor, so a cache made on
another machine or with another numba is ignored and the kernels compile as they would
have. Set ``CATGRAPH_BUILD_KERNEL_CACHE=0`` to skip the step; if it fails, the build goes
on without the cache.
"""

import os
import subprocess
import sys
import time

from setuptools import setup
from setuptools.command.build_py import build_py


class build_py_with_kernel_cache(build_py):
    """``build_py``, then ``catgraph warm-up`` run on the built package."""

    def run(self):
        super().run()
        if self.dry_run or getattr(self, "editable_mode", False):  # an editable install runs the sources in place
            return
        cache = os.path.join(self.build_lib, "catgraph", "__pycache__")
        if os.path.isdir(cache):  # an earlier build's files (pip builds in the tree): never shipped as they are
            for name in os.listdir(cache):
                if name.endswith((".nbi", ".nbc")):
                    os.remove(os.path.join(cache, name))
        if os.environ.get("CATGRAPH_BUILD_KERNEL_CACHE", "1") == "0":
            return
        env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}  # numba's in-tree cache
        # the built package first; the rest of the path as the build has it (pip's isolated build
        # environment reaches its packages through it)
        env["PYTHONPATH"] = os.pathsep.join(p for p in (os.path.abspath(self.build_lib), env.get("PYTHONPATH")) if p)
        start = time.perf_counter()
        try:
            subprocess.run([sys.executable, "-c", "import sys; from catgraph.cli.main import main; "
                            "sys.exit(main(['warm-up', '--quiet']))"],
                           env=env, check=True, timeout=900, cwd=os.path.abspath(self.build_lib))
        except (OSError, subprocess.SubprocessError) as err:
            print(f"catgraph: the kernels were not compiled into the build ({err}); they compile on first use",
                  file=sys.stderr)
            return
        print(f"catgraph: kernels compiled and cached into the build in {time.perf_counter() - start:.0f} s",
              file=sys.stderr)


setup(cmdclass={"build_py": build_py_with_kernel_cache})
