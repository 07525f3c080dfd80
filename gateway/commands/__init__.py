"""One module per ``python -m gateway`` subcommand (see gateway.cli)."""
