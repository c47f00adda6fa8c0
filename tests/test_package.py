import subprocess
import sys

import catgraph


def test_every_public_name_resolves():
    for name in catgraph.__all__:
        assert getattr(catgraph, name) is not None, name


def test_import_is_light():
    code = ("import sys, catgraph; heavy = [m for m in ('matplotlib', 'dask', 'distributed', 'numba') "
            "if m in sys.modules]; print(','.join(heavy))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == ""
