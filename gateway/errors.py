"""The project's one error tree: every deliberate failure is a GatewayError.

Messages say what was expected and what was got. The command lines turn these into
one-line messages and non-zero exit codes; anything else is a bug.
"""

from __future__ import annotations


class GatewayError(Exception):
    """Base of every error this project raises on purpose."""

    exit_code = 1


class InputError(GatewayError):
    """Bad user input: a file, an option, a scenario name."""

    exit_code = 2


class CsvFormatError(InputError):
    """A malformed interchange CSV; names the file, line and column."""

    def __init__(self, path: str, line: int, column: str | None, message: str) -> None:
        where = f"{path}:{line}" + (f": column {column!r}" if column else "")
        super().__init__(f"{where}: {message}")
        self.path = path
        self.line = line
        self.column = column


class ConfigError(GatewayError):
    """Bad configuration; exits with EX_CONFIG (78) as systemd expects."""

    exit_code = 78


class ModelError(GatewayError):
    """Vehicle-model parameters or dimensions out of their valid range."""


class DbcError(GatewayError):
    """The DBC database is missing, malformed or lacks an expected message."""


class FrameError(GatewayError):
    """A CAN frame failed validation (length, CRC, counter, range)."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


class EstimatorError(GatewayError):
    """The estimator was fed something it cannot use (shape, NaN, sensor count)."""


class StateError(GatewayError):
    """Persisted state could not be read or written."""
