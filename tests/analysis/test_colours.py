"""One colour per algorithm and structure, whatever else a figure shows (issue 53)."""

from __future__ import annotations

from heurtune.analysis.colours import FIXED, base_name, colours_of
from heurtune.analysis.figures import algorithm_colors


def test_a_name_keeps_its_colour_whatever_else_is_present():
    alone = colours_of(["cs"])["cs"]
    assert colours_of(["cs", "apso"])["cs"] == alone
    assert colours_of(["pso", "lshade", "jso", "cs", "random_search"])["cs"] == alone
    # the thesis' labels and the runner's names, the report's variants: cuckoo search's colour
    assert colours_of(["CS", "APSO"])["CS"] == alone
    assert colours_of(["cs (run 3)"])["cs (run 3)"] == alone
    assert algorithm_colors(["cmaes", "cs"])["cs"] == alone
    # an unknown name has a colour of its own, the same in every figure
    assert colours_of(["my_de"])["my_de"] == colours_of(["my_de", "cs", "ga"])["my_de"]


def test_names_of_one_figure_never_share_a_colour():
    names = sorted(FIXED) + [f"plugin_{i}" for i in range(6)]
    for chunk in (names[:10], names[10:20], names[-20:]):
        colours = colours_of(chunk)
        assert len(set(colours.values())) == len(chunk)


def test_base_names():
    assert base_name("CS [seed1]") == "cs" and base_name("gpm (run 0), failed: unstable") == "gpm"
    assert base_name("2-DOF PI") == "2-dof pi"
    assert colours_of(["2-DOF PI"])["2-DOF PI"] == colours_of(["pi2dof"])["pi2dof"]  # its label, its type
