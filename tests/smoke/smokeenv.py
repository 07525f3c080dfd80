"""The smoke suite's installed venv: build the wheel, install it into a fresh venv.

The venv lives under pytest's temporary directory, outside the source tree, and gets the
wheel with a normal (non-editable) ``pip install``; its dependencies come from the same
package index and pip cache as the development venv. Commands then run from a work
directory outside the tree, with no PYTHONPATH, so only the installed files can answer.
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))
from test_packaging import build_dists  # noqa: E402  (one build recipe for both suites)

INSTALL_TIMEOUT_S = 900.0


@dataclass(frozen=True)
class Installed:
    """A venv with the wheel installed, and a work directory outside the source tree."""

    venv: Path
    wheel: Path
    work: Path

    @property
    def python(self) -> Path:
        return self.venv / "bin" / "python"

    def exe(self, name: str) -> str:
        return str(self.venv / "bin" / name)

    def env(self, **extra: str) -> dict[str, str]:
        """The caller's environment without anything that could reach the source tree."""
        env = {k: v for k, v in os.environ.items()
               if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV", "NUMBA_CACHE_DIR",
                            "PYTHONSTARTUP", "NOTIFY_SOCKET")}
        env["PATH"] = f"{self.venv / 'bin'}{os.pathsep}{env.get('PATH', '')}"
        env["VIRTUAL_ENV"] = str(self.venv)
        env.update(extra)
        return env

    def run(self, argv: Sequence[str | Path], timeout_s: float = 300.0,
            env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
        """Run a command from the work directory; stdout and stderr as text."""
        return subprocess.run([str(a) for a in argv], cwd=self.work, env=env or self.env(),
                              capture_output=True, text=True, timeout=timeout_s)


def _pip(python: Path, *args: str) -> None:
    proc = subprocess.run([str(python), "-m", "pip", "install", "-q",
                           "--disable-pip-version-check", *args],
                          capture_output=True, text=True, timeout=INSTALL_TIMEOUT_S)
    assert proc.returncode == 0, f"pip install {args} failed:\n{proc.stdout}\n{proc.stderr}"


def install(base: Path) -> Installed:
    """Build the sdist and wheel into ``base/dist``, make ``base/venv``, install the wheel."""
    assert ROOT not in base.resolve().parents, f"smoke venv {base} must be outside {ROOT}"
    _, wheel = build_dists(base / "dist")
    venv = base / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=120)
    _pip(venv / "bin" / "python", str(wheel))
    work = base / "work"
    work.mkdir()
    inst = Installed(venv=venv, wheel=wheel, work=work)
    # what the README tells an integrator to run once after installing: the estimator's
    # kernels compiled into the fresh venv's numba cache, one per core (minutes)
    proc = inst.run([inst.python, "-m", "gateway.estimator.precompile"], timeout_s=1800)
    assert proc.returncode == 0 and "kernels ready" in proc.stdout, \
        f"precompile failed:\n{proc.stdout}\n{proc.stderr[-3000:]}"
    return inst
