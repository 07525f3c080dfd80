"""The service's persisted state: a state directory written atomically and read at start-up.

``StateStore`` is the entry point; ``files`` holds the durable-write primitives,
``segments`` the bounded logs, ``ledger`` the alert-seq reservation and ``codec`` the
record formats. The directory layout is in :mod:`gateway.sinks.store.store` and
``docs/alerts.md``.
"""

from gateway.sinks.store.codec import (
    AlertEntry,
    AuditEntry,
    BaselineEntry,
    Checkpoint,
    EstimateEntry,
)
from gateway.sinks.store.segments import LogBounds
from gateway.sinks.store.store import (
    ALERTS,
    AUDIT,
    BASELINES,
    CHECKPOINT,
    ESTIMATES,
    ESTIMATES_PREVIOUS,
    POLICY,
    SEQ_LEDGER,
    StateStore,
)

__all__ = [
    "ALERTS", "AUDIT", "BASELINES", "CHECKPOINT", "ESTIMATES", "ESTIMATES_PREVIOUS", "POLICY",
    "SEQ_LEDGER", "AlertEntry", "AuditEntry", "BaselineEntry", "Checkpoint", "EstimateEntry",
    "LogBounds", "StateStore",
]
