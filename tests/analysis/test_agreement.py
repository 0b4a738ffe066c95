"""heurtune.analysis.agreement: results from another CPU or release agree within the
tolerances of shipped numbers (docs/testing.md), and a move beyond them is named."""

import numpy as np
import pandas as pd

from heurtune.analysis.agreement import field_tolerance, frame_differences, text_differences, values_agree


def test_each_metric_has_its_tolerance():
    assert field_tolerance("J@nominal") == (1e-9, 0.0)
    assert field_tolerance("IAE2@+30%") == (1e-9, 0.0)
    assert field_tolerance("Q11") == (1e-9, 0.0)
    assert field_tolerance("ess1@-30%") == (0.0, 1e-10)
    assert field_tolerance("hmax") == (0.0, 1e-9)
    assert field_tolerance("ts2@nominal") == (0.0, 1e-8)
    assert field_tolerance("umin@nominal") == (0.0, 1e-8)


def test_values_agree_within_and_not_beyond():
    assert values_agree(4283.77, 4283.77 * (1 + 5e-10), "J")
    assert not values_agree(4283.77, 4283.77 * (1 + 2e-9), "J")
    assert values_agree(2.4, 2.4 + 5e-11, "ess1") and not values_agree(2.4, 2.4 + 2e-10, "ess1")
    assert values_agree(np.nan, np.nan, "J") and not values_agree(np.nan, 1.0, "J")
    assert values_agree(np.inf, np.inf, "J") and not values_agree(np.inf, -np.inf, "J")
    assert values_agree("abc", "abc") and not values_agree(30, 31, "n_evals")


def test_frames_compare_floats_by_tolerance_and_the_rest_exactly():
    x = pd.DataFrame({"problem_id": ["a", "b"], "n_evals": [30, 30], "J@nominal": [1.0, np.nan],
                      "ess1@nominal": [2.0, 3.0], "x": [np.array([1.0, 2.0]), np.array([3.0, 4.0])]})
    near = x.assign(**{"J@nominal": [1.0 + 5e-10, np.nan], "ess1@nominal": [2.0 + 5e-11, 3.0]})
    near["x"] = [np.array([1.0, 2.0 * (1 + 5e-10)]), np.array([3.0, 4.0])]
    assert frame_differences(x, near) == []
    far = x.assign(**{"J@nominal": [1.0 + 2e-9, np.nan], "n_evals": [30, 31]})
    lines = frame_differences(x, far)
    assert [line.split(":")[0] for line in lines] == ["n_evals", "J@nominal"]
    assert frame_differences(x, x.assign(**{"J@nominal": [1.0, 1.0]}))  # NaN against a number
    assert frame_differences(x, x.drop(columns="x")) and frame_differences(x, x.iloc[:1])


def test_texts_agree_on_their_words_and_printed_digits():
    a = "| cs | 4283.77 | 1.2e-03 |\n"
    assert text_differences(a, a) == []
    assert text_differences(a, "| cs | 4283.78 | 1.2e-03 |\n") == []  # one unit in the last place
    assert text_differences(a, "| cs | 4283.79 | 1.2e-03 |\n") == ["4283.77 against 4283.79"]
    assert text_differences(a, "| apso | 4283.77 | 1.2e-03 |\n") == ["the text around the numbers differs"]
