"""List the registered optimisers: ``python -m heurtune.algorithms [--markdown]``.

``--markdown`` prints the reference page ``docs/optimisers_reference.md`` (a test checks that
the page in the repository is what this prints).
"""

import sys

from heurtune.core import registry

if "--markdown" in sys.argv[1:]:
    print(registry.reference_markdown(), end="")
else:
    for name in registry.available():
        print(registry.describe(name))
