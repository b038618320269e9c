"""`mazelab.study(...)` (mazelab.experiments.api) refuses arguments of the wrong type or value in one
line naming the argument (TypeError for a type, ValueError for a value) before any run: runs=True is
no run count, sigma=[] no study, filters=[object] no filter, dask=42 no cluster."""

from __future__ import annotations

import numpy as np
import pytest

import mazelab

SMALL = {"maze": "paper_5x5", "runs": 1, "steps": 3, "particles": 20, "filters": ["sir"], "seed": 1}


@pytest.mark.parametrize(
    ("given", "error", "message"),
    [
        ({"runs": True}, TypeError, "runs must be a whole number, got True"),
        ({"runs": 2.0}, TypeError, "runs must be a whole number, got 2.0"),
        ({"steps": "3"}, TypeError, "steps must be a whole number"),
        ({"sigma": []}, ValueError, "sigma is empty"),
        ({"sigma": "0.3"}, TypeError, "sigma takes a number or a list of them, got '0.3'"),
        ({"sigma": [0.3, True]}, TypeError, "sigma takes a number or a list of them, got True"),
        ({"particles": [100, 1.5]}, TypeError, "particles takes a whole number or a list of them, got 1.5"),
        ({"delta": ()}, ValueError, "delta is empty"),
        ({"estimate": [1]}, ValueError, "estimate must be one of mean, mode, got 1"),  # by its declaration
        ({"filters": [object]}, TypeError, "filters: object is not a filter class: it has no class attribute 'name'"),
        ({"filters": [42]}, TypeError, "filters takes filter names or filter classes or a list of them, got 42"),
        ({"filters": []}, ValueError, "filters is empty"),
        ({"dask": 42}, TypeError, "dask must be a scheduler address like 'tcp://HOST:8786' or a distributed.Client"),
        ({"workers": 0}, ValueError, "workers must be >= 1"),
        ({"workers": True}, TypeError, "workers must be a whole number"),
        ({"seed": -1}, ValueError, "seed must be a whole number in [0, 2**128)"),
        ({"seed": "1"}, TypeError, "seed must be a whole number"),
        ({"kld": 1}, TypeError, "kld must be True or False"),
        ({"traces": "yes"}, TypeError, "traces must be True or False"),
        ({"kidnap_at": 1.5}, TypeError, "kidnap_at must be a whole number"),
        ({"maze": 42}, TypeError, "maze takes a maze file or shipped name"),
    ],
)
def test_a_wrong_argument_is_one_line_naming_it(given, error, message):
    with pytest.raises(error) as raised:
        mazelab.study(**{**SMALL, **given})
    assert message in str(raised.value) and "\n" not in str(raised.value)


def test_values_lists_tuples_and_arrays_are_all_taken():
    one = mazelab.study(**{**SMALL, "runs": 2, "sigma": [0.3, 0.4]})
    assert len(one.rows) == 4
    for sigma in ((0.3, 0.4), np.array([0.3, 0.4])):
        again = mazelab.study(**{**SMALL, "sigma": sigma, "runs": np.int64(2)})
        assert [r["final_error"] for r in again.rows] == [r["final_error"] for r in one.rows]
