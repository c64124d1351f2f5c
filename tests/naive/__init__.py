"""Pure-NumPy oracles for the numba kernels, one module per area (STYLE.md: tests/naive).

Obviously-correct, slow reference implementations; tests compare fast kernels against them.
"""
