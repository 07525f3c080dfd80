"""The wheel holds exactly the tracked product sources: no module lost, no test shipped.

``python -m build`` makes the sdist and, from it, the wheel (as CI and an integrator
would); the wheel's files are compared with ``git ls-files`` of ``gateway/``,
``firmware_sim/`` and ``dbc/`` (a filesystem walk outside a git checkout). The old
explicit ``packages = [...]`` list lost every subpackage (issue 11); package discovery
cannot, and this test keeps it so.
"""

from __future__ import annotations

import fcntl
import hashlib
import shutil
import subprocess
import sys
import tarfile
import tempfile
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PRODUCT = ("gateway", "firmware_sim", "dbc")
DATA = {"dbc/railgw.dbc"}                       # package data that must ship


def tracked_sources(root: Path = ROOT) -> set[str]:
    """Product files a clean clone has: ``.py`` under PRODUCT, plus DATA (POSIX paths)."""
    if (root / ".git").exists() and shutil.which("git"):
        out = subprocess.run(["git", "ls-files", "--", *PRODUCT], cwd=root, check=True,
                             capture_output=True, text=True).stdout.split()
    else:
        out = [p.relative_to(root).as_posix() for top in PRODUCT for p in (root / top).rglob("*")
               if p.is_file() and "__pycache__" not in p.parts]
    return {p for p in out if p.endswith(".py")} | (DATA & set(out))


def build_dists(out_dir: Path, root: Path = ROOT) -> tuple[Path, Path]:
    """``python -m build`` (sdist, then the wheel from the sdist) -> (sdist, wheel).

    One build of a source tree at a time (a lock beside the system's temporary files):
    the sdist step writes the tree's ``*.egg-info``, and the packaging check and the
    smoke suite may run at once under pytest-xdist.
    """
    tree = hashlib.sha256(str(root.resolve()).encode()).hexdigest()[:16]
    lock = Path(tempfile.gettempdir()) / f"railgw-build-{tree}.lock"
    with open(lock, "w") as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        proc = subprocess.run([sys.executable, "-m", "build", "--outdir", str(out_dir),
                               str(root)], capture_output=True, text=True)
    assert proc.returncode == 0, f"python -m build failed:\n{proc.stdout[-3000:]}{proc.stderr}"
    (sdist,), (wheel,) = out_dir.glob("*.tar.gz"), out_dir.glob("*.whl")
    return sdist, wheel


@pytest.fixture(scope="module")
def dists(tmp_path_factory) -> tuple[Path, Path]:
    return build_dists(tmp_path_factory.mktemp("dist"))


def test_wheel_modules_equal_the_tracked_sources(dists):
    _, wheel = dists
    names = zipfile.ZipFile(wheel).namelist()
    info = {n for n in names if n.split("/")[0].endswith(".dist-info")}
    shipped = set(names) - info
    tracked = tracked_sources()
    missing, extra = sorted(tracked - shipped), sorted(shipped - tracked)
    assert not missing, f"tracked sources missing from the wheel: {missing}"
    assert not extra, (f"the wheel has files that are not tracked product sources "
                       f"(untracked module? test code?): {extra}")
    assert {"gateway/commands/run.py", "gateway/sinks/store/__init__.py",
            "gateway/console/__init__.py", "gateway/identify/__init__.py"} <= shipped


def test_sdist_carries_the_sources_and_the_dbc(dists):
    sdist, _ = dists
    with tarfile.open(sdist) as tar:
        names = {n.split("/", 1)[1] for n in tar.getnames() if "/" in n}
    assert tracked_sources() <= names
    assert {"pyproject.toml", "README.md"} <= names


def test_metadata_licence_and_entry_points(dists):
    _, wheel = dists
    with zipfile.ZipFile(wheel) as zf:
        info = next(n.split("/")[0] for n in zf.namelist() if n.endswith(".dist-info/METADATA"))
        meta = zf.read(f"{info}/METADATA").decode()
        entry = zf.read(f"{info}/entry_points.txt").decode()
    assert "License-Expression: LicenseRef-Proprietary" in meta.splitlines()
    assert "railgw = gateway.cli:main" in entry and "railgw-sim = firmware_sim.cli:main" in entry
