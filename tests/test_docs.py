"""Generated documentation stays current."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_optimiser_reference_page_is_current():
    # In a fresh interpreter: tests register toy plugins that must not appear on the page.
    out = subprocess.run([sys.executable, "-m", "heurtune.algorithms", "--markdown"], check=True,
                         capture_output=True, text=True).stdout
    page = (ROOT / "docs" / "optimisers_reference.md").read_text()
    assert out == page, "regenerate with: python -m heurtune.algorithms --markdown > docs/optimisers_reference.md"


def test_listing_names_every_optimiser():
    out = subprocess.run([sys.executable, "-m", "heurtune.algorithms"], check=True, capture_output=True,
                         text=True).stdout
    for name in ("cs", "apso", "firefly", "pso", "ga", "sqp_multistart", "steepest_descent", "dfp", "bfgs",
                 "newton_raphson"):
        assert f"{name}: " in out
