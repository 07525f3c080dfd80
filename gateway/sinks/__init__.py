"""Outputs: CAN and log sinks, the state directory."""
