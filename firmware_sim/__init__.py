"""Sensor-node simulator: vehicle-model truth, CAN nodes with clocks, scenarios, playback."""
