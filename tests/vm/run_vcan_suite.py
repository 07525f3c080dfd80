"""Run the vcan test suite: directly where vcan0 exists, else in a virtme-ng VM (qemu TCG).

Usage (the project's venv python; ``tests/vm/run-vcan-suite.sh`` wraps this)::

    python tests/vm/run_vcan_suite.py [--results DIR] [--timeout-s 540] [-- PYTEST ARGS]

Where ``vcan0`` exists and AF_CAN works (a Linux laptop after ``modprobe vcan``), it
runs ``pytest -m vcan tests/vcan`` here. Otherwise it boots the Debian kernel cached by
``tests/vm/setup.sh`` with virtme-ng (``--disable-kvm``: KVM hangs on these machines),
whose guest sees this machine's filesystem as its root, creates ``vcan0`` inside and
runs the same pytest command there. The guest writes its pytest output, junit XML and
exit status into a shared results directory (``--rwdir``), which this runner follows
live and summarises. Exit status: the suite's, or 1 when it ran no test or the VM
did not finish.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
CHANNEL = "vcan0"
SUITE = "tests/vcan"
# virtme-ng mounts empty tmpfs over these in the guest: host paths below them are hidden.
GUEST_MASKED = ("/var/cache", "/var/tmp", "/var/log", "/var/lib/apt", "/var/lib/private")
VCAN_SETUP_FAILED = 97
"""Guest status when vcan0 could not be created (no test ran)."""


def cache_dir() -> Path:
    """The cache of tests/vm/setup.sh (same rule as there)."""
    env = os.environ.get("RAILGW_VM_CACHE")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(xdg) / "railgw-vm"


def host_has_vcan(channel: str = CHANNEL) -> bool:
    """True if ``channel`` exists here and the kernel speaks AF_CAN."""
    if not Path("/sys/class/net", channel).exists():
        return False
    try:
        with socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW) as s:
            s.bind((channel,))
    except (OSError, AttributeError):
        return False
    return True


@dataclass(frozen=True)
class Counts:
    """Test counts of one junit XML file."""

    tests: int
    failed: int
    errors: int
    skipped: int

    @property
    def passed(self) -> int:
        return self.tests - self.failed - self.errors - self.skipped


def junit_counts(path: Path) -> Counts | None:
    """Counts summed over the test suites of ``path``; None if missing or unreadable."""
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError):
        return None
    suites = [root] if root.tag == "testsuite" else list(root.iter("testsuite"))
    total = [0, 0, 0, 0]
    for s in suites:
        for i, key in enumerate(("tests", "failures", "errors", "skipped")):
            total[i] += int(s.get(key, "0"))
    return Counts(*total)


def pytest_cmd(python: str, results: Path, extra: list[str], *, vm: bool) -> list[str]:
    # In the VM the project is read-only (no pytest cache) and every import costs
    # seconds under TCG (hypothesis' plugin is not needed by the vcan tests).
    vm_opts = ["-p", "no:cacheprovider", "-p", "no:hypothesispytest"] if vm else []
    return [python, "-m", "pytest", *vm_opts, "-m", "vcan", SUITE, "-v",
            f"--junitxml={results / 'junit.xml'}", "-o", "junit_suite_name=vcan", *extra]


def report(counts: Counts | None, status: int | None, where: str, timings: str) -> int:
    """Print the summary lines; return the runner's exit status."""
    if counts is None:
        print(f"== vcan suite ({where}): no junit XML came back (status {status}){timings}")
        return status if status else 1
    print(f"== vcan suite ({where}): {counts.tests} tests ran{timings}")
    print(f"vcan: {counts.passed} passed, {counts.failed + counts.errors} failed, "
          f"{counts.skipped} skipped")
    if status is None:
        print("== vcan suite: no exit status came back", file=sys.stderr)
        return 1
    if status == 0 and counts.passed == 0:
        print("== vcan suite: ran no vcan test (a skipped suite does not count)",
              file=sys.stderr)
        return 1
    return status


def run_on_host(results: Path, extra: list[str]) -> int:
    print(f"== vcan suite: {CHANNEL} exists here: running {SUITE} directly", flush=True)
    env = dict(os.environ, RAILGW_VCAN_REQUIRED="1")
    t0 = time.monotonic()
    status = subprocess.call(pytest_cmd(sys.executable, results, extra, vm=False), cwd=ROOT,
                             env=env)
    return report(junit_counts(results / "junit.xml"), status, "host",
                  f" in {time.monotonic() - t0:.0f} s")


# ---------------------------------------------------------------- the VM
def loose_dirs(python: str) -> list[Path]:
    """Directories the guest re-mounts with the 9p page cache on (cache=loose, read-only).

    virtme-ng exports the host root without a page cache, so every python process
    re-reads the standard library and site-packages over 9p; cached mounts of the
    project, its venv and the base interpreter make the second read free. A masked
    directory (GUEST_MASKED) holding one of them becomes visible this way too.
    """
    out = [ROOT]
    info = subprocess.run([python, "-c", "import sys; print(sys.prefix); print(sys.base_prefix)"],
                          capture_output=True, text=True, check=True).stdout.split()
    for p in map(Path, info):
        if not any(p == d or d in p.parents for d in out):
            out.append(p)
    return out


def guest_script(results: Path, cache: Path, python: str, loose: list[Path],
                 suite_timeout_s: int, extra: list[str]) -> str:
    """The bash script the guest runs (written into the shared results directory)."""
    r = shlex.quote(str(results))
    rw = [shlex.quote(str(d)) for d in (results, cache / "numba")]
    # A cached mount over a parent of a shared read-write directory would hide it:
    # park the read-write mounts under /run first and bind them back afterwards.
    park = "\n".join(f"mkdir -p /run/rgw-rw{i} && mount --bind {d} /run/rgw-rw{i}"
                     for i, d in enumerate(rw))
    unpark = "\n".join(f"mount --bind /run/rgw-rw{i} {d}" for i, d in enumerate(rw))
    mounts = "\n".join(
        f"mkdir -p {shlex.quote(str(d))} 2>/dev/null; mount -t 9p -o trans=virtio,"
        f"version=9p2000.L,msize=512000,cache=loose,ro rgwc{i} {shlex.quote(str(d))} "
        f"|| echo 'warning: no cached mount of {d}'"
        for i, d in enumerate(loose))
    env = {
        "HOME": os.environ.get("HOME", "/root"), "LANG": "C.UTF-8",
        "PATH": f"{Path(python).parent}:/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:"
                "/sbin:/bin",
        "PYTHONDONTWRITEBYTECODE": "1", "PYTHONUNBUFFERED": "1",
        # Compiled numba kernels are shared with the host warm-up (tests/vm/prewarm.py):
        # a generic CPU target gives host and guest (qemu -cpu max) the same cache key.
        "NUMBA_CACHE_DIR": str(cache / "numba"), "NUMBA_CPU_NAME": "generic",
        "RAILGW_VCAN_REQUIRED": "1", "RAILGW_IN_VM": "1",
        "RAILGW_VCAN_DATA": str(results / "data"),
    }
    for name in ("CI", "RAILGW_VCAN_GATEWAY"):
        if name in os.environ:
            env[name] = os.environ[name]
    exports = "\n".join(f"export {k}={shlex.quote(v)}" for k, v in env.items())
    cmd = " ".join(shlex.quote(a) for a in pytest_cmd(python, results, extra, vm=True))
    return f"""#!/bin/bash
# Generated by tests/vm/run_vcan_suite.py; runs inside the VM as root.
exec >{r}/guest.log 2>&1
up() {{ cut -d' ' -f1 /proc/uptime; }}
echo "guest_start_s=$(up)" > {r}/times
{park}
{mounts}
{unpark}
if ! (modprobe vcan && ip link add dev {CHANNEL} type vcan && ip link set up {CHANNEL}); then
  echo "could not create {CHANNEL}"; echo {VCAN_SETUP_FAILED} > {r}/status; exit 0
fi
ip -details link show {CHANNEL}
{exports}
cd {shlex.quote(str(ROOT))}
echo "suite_start_s=$(up)" >> {r}/times
timeout --kill-after=10 {suite_timeout_s} {cmd} > {r}/pytest.log 2>&1
status=$?
echo "suite_end_s=$(up)" >> {r}/times
echo $status > {r}/status
sync
"""


def host_prepare(python: str, cache: Path, data: Path) -> None:
    """Work the guest would do slowly under TCG: byte-compile, warm the numba cache,
    record the gateway test's traffic into ``data``."""
    t0 = time.monotonic()
    # The project's .pyc (PYTHONDONTWRITEBYTECODE may have kept them from being written).
    subprocess.run([python, "-m", "compileall", "-q", "-j", "0", "gateway", "firmware_sim",
                    "dbc", "tests"], cwd=ROOT, check=False, stdout=subprocess.DEVNULL)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache / "numba"), NUMBA_CPU_NAME="generic",
               RAILGW_VCAN_DATA=str(data))
    proc = subprocess.run([python, str(ROOT / "tests/vm/prewarm.py")], cwd=ROOT, env=env,
                          capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        print(f"warning: host warm-up failed (the guest will compile and record):\n"
              f"{proc.stderr[-2000:]}")
    print(f"== vcan suite: host warm-up (pyc, numba cache, gateway traffic) took "
          f"{time.monotonic() - t0:.0f} s", flush=True)


def follow(path: Path, pos: int) -> int:
    """Print what was appended to ``path`` since ``pos``; returns the new position."""
    try:
        with path.open("rb") as f:
            f.seek(pos)
            chunk = f.read()
    except FileNotFoundError:
        return pos
    if chunk:
        sys.stdout.write(chunk.decode("utf-8", "replace"))
        sys.stdout.flush()
    return pos + len(chunk)


def read_times(path: Path) -> dict[str, float]:
    out: dict[str, float] = {}
    if path.exists():
        for line in path.read_text().split():
            key, _, value = line.partition("=")
            with contextlib.suppress(ValueError):
                out[key] = float(value)
    return out


def run_in_vm(results: Path, timeout_s: float, extra: list[str], memory: str) -> int:
    cache = cache_dir().resolve()
    vng = cache / "venv/bin/vng"
    kver_file = cache / "kernel/current"
    kver = kver_file.read_text().strip() if kver_file.exists() else ""
    kimg = cache / "kernel" / kver / "boot" / f"vmlinuz-{kver}"
    if not (vng.exists() and kver and kimg.exists() and shutil.which("qemu-system-x86_64")):
        print(f"== vcan suite: no {CHANNEL} here and the VM is not set up in {cache}: "
              "run tests/vm/setup.sh", file=sys.stderr)
        return 2
    for d in (cache, results):
        if any(str(d).startswith(m + "/") for m in GUEST_MASKED):
            print(f"== vcan suite: {d} would be hidden in the guest (under one of "
                  f"{GUEST_MASKED}); choose another place", file=sys.stderr)
            return 2
    python = str(ROOT / ".venv/bin/python") if (ROOT / ".venv/bin/python").exists() \
        else sys.executable
    print(f"== vcan suite: no {CHANNEL} here: booting kernel {kver} in qemu (TCG) with "
          f"virtme-ng; results in {results}", flush=True)
    host_prepare(python, cache, results / "data")
    loose = loose_dirs(python)
    suite_timeout_s = max(60, int(timeout_s) - 90)
    script = results / "guest.sh"
    script.write_text(guest_script(results, cache, python, loose, suite_timeout_s, extra))
    qemu_opts = " ".join(
        f"-fsdev local,id=rgwc{i},path={d},security_model=none,readonly=on,multidevs=remap "
        f"-device virtio-9p-pci,fsdev=rgwc{i},mount_tag=rgwc{i}" for i, d in enumerate(loose))
    cmd = [str(vng), "--disable-kvm", "--run", str(kimg), "--memory", memory,
           "--rwdir", str(results), "--rwdir", str(cache / "numba"),
           f"--qemu-opts={qemu_opts}", "--exec", f"bash {shlex.quote(str(script))}"]
    env = dict(os.environ, PATH=f"{vng.parent}:{os.environ.get('PATH', '/usr/bin:/bin')}")
    t0 = time.monotonic()
    with (results / "vng.log").open("wb") as log:
        proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdin=subprocess.DEVNULL, stdout=log,
                                stderr=subprocess.STDOUT, start_new_session=True)
        pos = 0
        timed_out = False
        while proc.poll() is None:
            pos = follow(results / "pytest.log", pos)
            if time.monotonic() - t0 > timeout_s:
                timed_out = True
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
                break
            time.sleep(1.0)
        follow(results / "pytest.log", pos)
    wall_s = time.monotonic() - t0
    times = read_times(results / "times")
    timings = f" (wall {wall_s:.0f} s"
    if "guest_start_s" in times:
        timings += f"; boot to guest script {times['guest_start_s']:.0f} s"
    if "suite_start_s" in times and "suite_end_s" in times:
        timings += f"; pytest {times['suite_end_s'] - times['suite_start_s']:.0f} s"
    timings += ")"
    status_file = results / "status"
    status = int(status_file.read_text()) if status_file.exists() else None
    if timed_out:
        print(f"== vcan suite: the VM did not finish within {timeout_s:.0f} s: killed",
              file=sys.stderr)
    if status is None or status == VCAN_SETUP_FAILED or timed_out:
        for name in ("guest.log", "vng.log"):
            p = results / name
            if p.exists():
                print(f"---- {name} (last 40 lines)")
                print("\n".join(p.read_text(errors="replace").splitlines()[-40:]))
    if status == VCAN_SETUP_FAILED:
        print(f"== vcan suite: the guest could not create {CHANNEL}", file=sys.stderr)
        return 1
    return report(junit_counts(results / "junit.xml"), status, "VM", timings)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--results", type=Path, default=None,
                        help="results directory (default: <cache>/results)")
    parser.add_argument("--timeout-s", type=float, default=540.0,
                        help="kill the VM after this long (default 540 s)")
    parser.add_argument("--memory", default="2G", help="guest memory (default 2G)")
    parser.add_argument("--vm", action="store_true",
                        help=f"use the VM even if {CHANNEL} exists here")
    parser.add_argument("pytest_args", nargs="*", help="extra pytest arguments (after --)")
    args = parser.parse_args(argv)
    results = (args.results or cache_dir() / "results").resolve()
    results.mkdir(parents=True, exist_ok=True)
    for name in ("junit.xml", "status", "pytest.log", "guest.log", "times", "vng.log"):
        (results / name).unlink(missing_ok=True)
    shutil.rmtree(results / "data", ignore_errors=True)   # recorded afresh each run
    if host_has_vcan() and not args.vm:
        return run_on_host(results, args.pytest_args)
    return run_in_vm(results, args.timeout_s, args.pytest_args, args.memory)


if __name__ == "__main__":
    sys.exit(main())
