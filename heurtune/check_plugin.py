"""``python -m heurtune.check_plugin``: check an optimiser plugin against the optimiser contract
(the command; the code is :mod:`heurtune.runner.check_plugin`)."""

from heurtune.runner.check_plugin import main

if __name__ == "__main__":
    main()
