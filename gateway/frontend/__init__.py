"""Frames to estimator samples: validation, clock sync, low-pass, resampler, gate."""
