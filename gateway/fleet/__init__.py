"""The fleet view: CAN logs from many vehicles -> Parquet store -> Dask replay -> trends.

An offline tool (``railgw fleet``, ``docs/fleet.md``); it never runs on the vehicle and
needs the ``fleet`` extra (dask[distributed], pyarrow). ``runs`` is its seam to the
gateway's stages (front end, estimator worker, alert policy) and ``onboard`` its seam to
the service's state directory (read through ``gateway.sinks.store.snapshot``);
``store``, ``replay``, ``trend`` and ``report`` work on their records and on the
Parquet files.
"""
