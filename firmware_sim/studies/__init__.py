"""Accuracy and speed studies of the gateway against the simulator."""
