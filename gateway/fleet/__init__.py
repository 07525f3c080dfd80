"""The fleet view: CAN logs from many vehicles -> Parquet store -> Dask replay -> trends.

An offline tool (``railgw fleet``, ``docs/fleet.md``); it never runs on the vehicle and
needs the ``fleet`` extra (dask[distributed], pyarrow). ``runs`` is its only module
that touches the gateway's stages; ``store``, ``replay``, ``trend`` and ``report`` work
on its records and on the Parquet files.
"""
