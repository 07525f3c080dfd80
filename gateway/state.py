"""The service's state directory, by its short name: re-exports :mod:`gateway.store`.

The store is a package (``files`` primitives, ``codec`` record formats, ``store`` the
``StateStore``), too large for one module; this module is the import the service uses.
"""

from gateway.store import (
    ALERTS,
    AUDIT,
    BASELINES,
    CHECKPOINT,
    ESTIMATES,
    ESTIMATES_PREVIOUS,
    POLICY,
    AlertEntry,
    AuditEntry,
    BaselineEntry,
    Checkpoint,
    EstimateEntry,
    StateStore,
)

__all__ = [
    "ALERTS", "AUDIT", "BASELINES", "CHECKPOINT", "ESTIMATES", "ESTIMATES_PREVIOUS", "POLICY",
    "AlertEntry", "AuditEntry", "BaselineEntry", "Checkpoint", "EstimateEntry", "StateStore",
]
