"""pytest at the repository root: the doctest collection of ``rimu/`` (``--doctest-modules`` in addopts) leaves out
the modules that exist only for an optional extra when that extra is not installed (the compiled kernels without
numba: importing them is an ImportError by design; their callers check the backend first)."""

try:
    import numba  # noqa: F401
except ImportError:
    collect_ignore = ["rimu/fusion/_kernels.py", "rimu/calibration/_hh_kernels.py", "rimu/session/_kernels.py",
                      "rimu/calibration/_lsq_kernels.py"]
