"""The daemon's import graph stays lean: ``gateway run`` loads no offline or study stack.

Under the unit's sandbox an import of the offline identification stack once killed the
service at start (SALib -> multiprocess -> dill calls ``tempfile.gettempdir()`` at import,
docs/vcan.md "systemd in the VM"). The daemon needs none of it, nor plotting, nor the
simulator, nor the fleet engine: this test keeps it so, in a fresh interpreter.
"""

from __future__ import annotations

import json
import subprocess
import sys

PROBE = """
import contextlib, io, json, sys
from gateway import cli
with contextlib.redirect_stdout(io.StringIO()):
    try:
        cli.main(["run", "--help"])
    except SystemExit:
        pass
import gateway.commands.run, gateway.service.daemon  # what ExecStart runs
print(json.dumps(sorted(sys.modules)))
"""

FORBIDDEN_TOP = ("SALib", "dill", "multiprocess", "matplotlib", "dask", "distributed",
                 "pyarrow", "firmware_sim")


def test_gateway_run_imports_no_offline_stack():
    out = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True,
                         check=True, timeout=120)
    modules = json.loads(out.stdout.strip().splitlines()[-1])
    bad = [m for m in modules
           if m.split(".")[0] in FORBIDDEN_TOP or m.startswith("gateway.identify")
           or m.startswith("gateway.fleet")]
    assert bad == [], f"gateway run imports {bad}"
