"""The testing rule of docs/testing.md holds in every test file: numbers are compared through
tests/numerics.py, which makes each comparison say whether it is bit for bit (and why), exact,
or within a stated tolerance."""

import ast
import pathlib

import numpy as np
import pandas as pd
import pytest
from numerics import SAME_STREAM, assert_close, assert_exact, assert_same_bits

TESTS = pathlib.Path(__file__).parent
FORBIDDEN_CALLS = {"assert_array_equal", "array_equal", "assert_frame_equal", "assert_series_equal",
                   "assert_equal"}


def _violations(path, root=TESTS):
    tree = ast.parse(path.read_text(), filename=str(path))
    negated = {id(node.operand) for node in ast.walk(tree)
               if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.Not)}
    found = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        func = node.func
        name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", None)
        # "not np.array_equal(a, b)" asserts a difference, which no tolerance can weaken
        if name in FORBIDDEN_CALLS and id(node) not in negated:
            found.append(f"{path.relative_to(root)}:{node.lineno}: {name}")
        for kw in node.keywords:
            if kw.arg == "check_exact" and isinstance(kw.value, ast.Constant) and kw.value.value is True:
                found.append(f"{path.relative_to(root)}:{node.lineno}: check_exact=True")
        # a tolerance of nothing is an exact comparison in disguise
        zero = {kw.arg for kw in node.keywords if kw.arg in ("rtol", "atol", "rel", "abs")
                and isinstance(kw.value, ast.Constant) and kw.value.value == 0}
        if name in ("allclose", "assert_allclose", "isclose", "approx") and (
                zero >= {"rtol", "atol"} or zero >= {"rel", "abs"}):
            found.append(f"{path.relative_to(root)}:{node.lineno}: {name} with no tolerance")
    return found


def test_no_test_compares_numbers_outside_the_rule():
    files = sorted(p for p in TESTS.rglob("*.py") if p.name != "numerics.py")
    assert len(files) > 50
    found = [v for p in files for v in _violations(p)]
    assert not found, ("compare through tests/numerics.py (assert_same_bits / assert_exact / assert_close, "
                       "docs/testing.md):\n" + "\n".join(found))


def test_the_checker_finds_a_bare_equality(tmp_path):
    bad = tmp_path / "test_bad.py"
    bad.write_text("import numpy as np\nnp.testing.assert_array_equal([1.0], [1.0])\n"
                   "assert not np.array_equal([1.0], [2.0])\nimport pandas as pd\n"
                   "pd.testing.assert_frame_equal(a, b, check_exact=True)\n"
                   "np.testing.assert_allclose(a, b, rtol=0, atol=0)\n"
                   "np.testing.assert_allclose(a, b, rtol=0, atol=1)\n")
    found = _violations(bad, root=tmp_path)
    assert [f.split(": ")[1] for f in found] == ["assert_array_equal", "assert_frame_equal", "check_exact=True",
                                                   "assert_allclose with no tolerance"]


def test_same_bits_names_its_design_and_is_strict():
    with pytest.raises(ValueError, match="not a same-stream design"):
        assert_same_bits([1.0], [1.0], because="close enough")
    for because in SAME_STREAM:
        assert_same_bits([1.0, np.nan], [1.0, np.nan], because=because)
    with pytest.raises(AssertionError):
        assert_same_bits([1.0], [np.nextafter(1.0, 2.0)], because="same seed")
    with pytest.raises(AssertionError):
        assert_same_bits([0.0], [-0.0], because="same seed", signed_zeros=True)
    frame = pd.DataFrame({"f": [0.1 + 0.2]})
    with pytest.raises(AssertionError):  # pandas' default would call 1e-16 apart equal
        assert_same_bits(frame, pd.DataFrame({"f": [0.3]}), because="workers")
    with pytest.raises(AssertionError):
        assert_exact(frame, pd.DataFrame({"f": [0.3]}))


def test_close_needs_its_reason_and_holds_its_tolerance():
    with pytest.raises(ValueError, match="because"):
        assert_close([1.0], [1.0], rtol=1e-9, because="")
    assert_close([1.0 + 1e-10, np.nan], [1.0, np.nan], rtol=1e-9, because="test")
    with pytest.raises(AssertionError, match="conditioning"):
        assert_close([1.0 + 1e-8], [1.0], rtol=1e-9, because="conditioning")
    assert_close(pd.DataFrame({"f": [1.0 + 1e-10], "i": [3]}), pd.DataFrame({"f": [1.0], "i": [3]}),
                 rtol=1e-9, because="test")
