"""Railway suspension condition-monitoring gateway: CAN in, RBPF estimates and alerts out."""

__version__ = "0.1.0"
