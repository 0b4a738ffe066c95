"""Plants, controllers, scenarios and metrics (imported as ``heurtune.objectives``).

Jitted kernels live in ``_kernels``; everything else is orchestration around them.
"""
