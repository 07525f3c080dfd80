"""The RBPF estimator: filter, Kalman and discretisation kernels, particles, monitor."""
