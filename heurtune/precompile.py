"""``python -m heurtune.precompile``: fill numba's cache with the shipped experiments' kernels (the
command; the code is :mod:`heurtune.runner.precompile`)."""

from heurtune.runner.precompile import main

if __name__ == "__main__":
    main()
