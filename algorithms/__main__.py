"""List the registered optimisers: ``python -m heurtune.algorithms``."""

from heurtune import registry

for name in registry.available():
    print(registry.describe(name))
