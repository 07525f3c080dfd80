"""Session fixture for the smoke suite: the wheel built and installed once (smokeenv)."""

from __future__ import annotations

import pytest
from smokeenv import Installed, install


@pytest.fixture(scope="session")
def installed(tmp_path_factory) -> Installed:
    return install(tmp_path_factory.mktemp("smoke"))
