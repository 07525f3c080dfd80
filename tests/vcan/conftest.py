"""The vcan tests run only where a kernel CAN interface is: skipped elsewhere, failed in the VM.

- ``vcan0`` here (a Linux machine after ``modprobe vcan``): they run.
- No ``vcan0`` but the VM is set up: skipped here; tests/vm/run-vcan-suite.sh runs
  them in the VM (as CI does, after the host pytest run).
- Neither: skipped with a one-line reason.
- ``RAILGW_VCAN_REQUIRED=1`` (set by the runner, in the VM and on the host): a missing
  vcan fails them instead, so the suite CI counts can never silently skip.
"""

from __future__ import annotations

import os
from collections.abc import Iterator

import pytest
import vcanlib

from gateway.can.codec import Codec, default_codec


def _required() -> bool:
    return os.environ.get("RAILGW_VCAN_REQUIRED") == "1"


def pytest_runtest_setup(item: pytest.Item) -> None:
    if item.get_closest_marker("vcan") is None:
        return
    reason = vcanlib.vcan_unavailable(vcanlib.CHANNEL)
    if reason is None:
        return
    if _required():
        pytest.fail(f"{reason}, but RAILGW_VCAN_REQUIRED=1", pytrace=False)
    if vcanlib.vm_ready():
        pytest.skip(f"{reason}: tests/vm/run-vcan-suite.sh runs these in a VM")
    pytest.skip(f"{reason} and no VM: see docs/vcan.md (tests/vm/setup.sh)")


@pytest.fixture()
def channel() -> str:
    """The shared vcan interface (vcan0); tests must not change its link."""
    return vcanlib.CHANNEL


@pytest.fixture()
def scratch() -> Iterator[str]:
    """A vcan interface of this test's own, up; it may take it down or delete it."""
    if os.geteuid() != 0:
        if _required():
            pytest.fail("creating a vcan interface needs root (CAP_NET_ADMIN)", pytrace=False)
        pytest.skip("creating a vcan interface needs root (CAP_NET_ADMIN)")
    with vcanlib.scratch_link() as name:
        yield name


@pytest.fixture(scope="session")
def codec() -> Codec:
    return default_codec()
