"""List the registered optimisers: ``python -m heurtune.algorithms [NAME ...] [--markdown]``.

``--markdown`` prints the reference page ``docs/optimisers_reference.md`` (a test checks that
the page in the repository is what this prints).
"""

import argparse
import sys

from heurtune.core import registry
from heurtune.core.errors import ConfigError


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m heurtune.algorithms",
                                 description="List the registered optimisers with their settings and sources.")
    ap.add_argument("names", nargs="*", help="only these optimisers (default: all)")
    ap.add_argument("--markdown", action="store_true", help="print the reference page docs/optimisers_reference.md")
    args = ap.parse_args(argv)
    if args.markdown:
        print(registry.reference_markdown(), end="")
        return 0
    try:
        for name in args.names or registry.available():
            print(registry.describe(name))
        if not args.names:
            for prefix, what in registry.bridges().items():
                print(f"{prefix}:<name>: {what} (the settings of a bridged one: python -m heurtune.algorithms "
                      f"{prefix}:<name>)")
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
