"""The service's persisted state: the state directory, and the alert policy restored from it.

The store is a package (``files`` primitives, ``segments`` bounded logs, ``ledger`` the
seq reservation, ``codec`` record formats, ``store`` the ``StateStore``:
:mod:`gateway.sinks.store`); this module adds :func:`restore_policy`, the one start-up
path from the directory to a running :class:`~gateway.alerts.policy.AlertPolicy` that
never stops the service.
"""

from __future__ import annotations

import logging

from gateway.alerts.policy import AlertPolicy, PolicyConfig
from gateway.errors import StateError
from gateway.records import Alert
from gateway.sinks.store import ALERTS, POLICY, StateStore

log = logging.getLogger(__name__)


def restore_policy(store: StateStore, config: PolicyConfig | None = None, *,
                   recent: int = 50) -> tuple[AlertPolicy, list[Alert]]:
    """``(policy, recent_alerts)``: the policy from the snapshot, the alert events newer
    than it and the seq ledger, reserving seqs through ``store``; and at least the
    ``recent`` newest events, oldest first.

    With a usable snapshot only the tail of the history is read (backwards from the
    end). A snapshot of the wrong shape is set aside (``store.quarantined``) and the
    policy is rebuilt from the whole retained history; history events that cannot be
    replayed are skipped. Each problem is logged at ERROR; nothing here raises for bad
    state, so a bad file cannot keep the service from starting.
    """
    snapshot = store.load_policy()
    since = snapshot.get("next_seq") if snapshot is not None else None
    if isinstance(since, int) and not isinstance(since, bool) and since >= 1:
        entries = store.read_alerts(last=recent, since_seq=since)
    else:
        entries = store.read_alerts()
    history = [e.alert for e in entries]
    upto = store.seq_reserved_upto()
    try:
        policy = AlertPolicy.restore(snapshot, config, history, reserved_upto=upto,
                                     reserve=store.reserve_seqs, strict=False)
    except StateError as err:
        store.quarantine(POLICY, str(err))
        history = [e.alert for e in store.read_alerts()]
        policy = AlertPolicy.restore(None, config, history, reserved_upto=upto,
                                     reserve=store.reserve_seqs, strict=False)
    for problem in policy.restore_problems:
        log.error("state: %s", problem)
        store.problems.append(f"{ALERTS} / {POLICY}: {problem}")
    return policy, history[-recent:] if recent else []
