"""CAN: DBC codec, E2E protection, bus load, bus specs, receive thread, log files."""
