"""``python -m gateway`` subcommands that need the simulator (entry points ``railgw.commands``)."""
