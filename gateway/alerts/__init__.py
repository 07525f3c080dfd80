"""The alert policy: thresholds, hysteresis, codes."""
