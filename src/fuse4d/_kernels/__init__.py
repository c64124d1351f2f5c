"""Private numba kernels. They only fill buffers: no validation, no allocation of results."""
