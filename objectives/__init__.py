"""Plant families, one subpackage each (imported as ``heurtune.objectives.<family>``).

Each family folder holds its model, controllers, jitted kernels (``kernels.py``), tuning
problem (``problem.py``), config schema and experiment class (``family.py``, registered with
:func:`heurtune.core.families.register_family`) and reports. What families share sits beside
them (``robustness.py``). A new family is a new folder here, or one plugin file (docs/plants.md).
"""
