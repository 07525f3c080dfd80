#!/usr/bin/env bash
# Install everything the project needs into .venv, then lint, type-check and test.
# This is the README's second set-up command; .ci/run calls it. Extra arguments go to
# pytest. pytest's exit status 5 (no tests ran) fails like any other failure.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if ! command -v systemd-analyze >/dev/null 2>&1; then
  echo "== installing Debian's systemd package (for systemd-analyze, used by the unit checks)"
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq systemd >/dev/null
  else
    echo "   not root or no apt-get: the systemd unit checks will be skipped"
  fi
fi
echo "== creating .venv and installing the project with its test tools"
[ -x .venv/bin/python ] || "$PY" -m venv .venv
.venv/bin/python -m pip install -q --disable-pip-version-check --upgrade pip
.venv/bin/python -m pip install -q --disable-pip-version-check -e '.[dev]'
echo "== ruff"
.venv/bin/ruff check .
echo "== mypy"
.venv/bin/mypy
echo "== pytest"
.venv/bin/python -m pytest "$@"
