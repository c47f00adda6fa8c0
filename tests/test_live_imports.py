"""What the live path loads: the streaming process keeps only the modules it runs.

Every module loaded stays resident for the life of a live process, beside the map and
the matcher's ring (``benchmarks/results/live.md``: the process before the map is most of
the streaming peak at ``N = 10^5``). ``import catgraph.live`` loads no compiled kernels
(numba loads with the first step), and neither the import nor a live step loads
``scipy.spatial`` or ``scipy.sparse`` (about 7 MB resident; only metric ground truth,
explicit ground-truth matrices and graphs built from positions need them, and import
them where they are used), nor ``catgraph.datasets`` (the loaders and the synthetic
world: 300 modules and about 12 MB resident).
"""

from __future__ import annotations

import json
import subprocess
import sys

SCRIPT = """
import json, sys
import catgraph, catgraph.live
after_import = sorted(sys.modules)
from catgraph.live import warm_up
warm_up(models=("combined",), layouts=("uint8",), steps=2)
print(json.dumps({"import": after_import, "step": sorted(sys.modules)}))
"""


def test_live_path_leaves_scipy_spatial_and_sparse_unloaded():
    out = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, check=True)
    loaded = json.loads(out.stdout.strip().splitlines()[-1])
    assert "catgraph.live" in loaded["import"] and "numba" not in loaded["import"]
    assert "numba" in loaded["step"]  # the step did run its kernels
    for when in ("import", "step"):
        heavy = [m for m in loaded[when] if m.split(".")[:2] in (["scipy", "spatial"], ["scipy", "sparse"])]
        assert heavy == [], f"{when}: {heavy[:5]}"
        # nor the loaders and the synthetic world (a live process is handed frames, not files)
        assert [m for m in loaded[when] if m.startswith("catgraph.datasets")] == [], when
