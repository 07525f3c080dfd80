"""The one pipeline (live and replay) and its estimator worker process."""
