#!/usr/bin/env bash
# Run the vcan tests: directly where vcan0 exists, else in the VM set up by
# tests/vm/setup.sh. Arguments go to tests/vm/run_vcan_suite.py (--help); pytest
# arguments after '--'. Exit status: the suite's (1 if it ran no test).
set -euo pipefail
cd "$(dirname "$0")/../.."
PY=.venv/bin/python
[ -x "$PY" ] || PY=${PYTHON:-python3}
exec "$PY" tests/vm/run_vcan_suite.py "$@"
