"""The shared text and JSON helpers (pneumatic_env.text_format)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from pneumatic_env.text_format import is_number, jsonable, number_text, value_text


@pytest.mark.parametrize(
    ("value", "plain", "finite"),
    [
        (1, True, True),
        (2.5, True, True),
        (np.float32(1), True, True),
        (math.nan, True, False),
        (math.inf, True, False),
        (True, False, False),
        (np.bool_(False), False, False),
        ("1", False, False),
        (None, False, False),
    ],
)
def test_is_number_refuses_booleans_and_with_finite_nan_and_inf(value, plain, finite):
    assert is_number(value) is plain
    assert is_number(value, finite=True) is finite


def test_value_text_shows_whole_numbers_floats_and_other_values():
    assert [value_text(v) for v in (20, np.int64(-3), -3.0, math.nan, "abc", True)] == [
        "20",
        "-3",
        "-3.0",
        "nan",
        "'abc'",
        "True",
    ]


def test_number_text_styles():
    assert number_text(0.1 + 0.2) == "0.30000000000000004"  # exact
    assert [number_text(v, 4) for v in (None, 1234.5678, math.inf, -math.inf, math.nan)] == [
        "-",
        "1235",
        "inf",
        "-inf",
        "nan",
    ]
    cell = dict(fixed=True, missing="", not_finite="")
    assert [number_text(v, 2, **cell) for v in (None, math.nan, 3.14159, "1.5 (est.)")] == [
        "",
        "",
        "3.14",
        "1.5 (est.)",
    ]
    speed = dict(missing="n/a", not_finite="n/a", grouped_from=1e3)
    assert [number_text(v, 3, **speed) for v in (None, math.inf, 12345.6, 0.012345)] == [
        "n/a",
        "n/a",
        "12,346",
        "0.0123",
    ]


def test_jsonable_turns_numpy_values_into_plain_json():
    data = {1: (np.float64(0.5), np.arange(2)), "b": [np.bool_(True), {"c": np.int32(3)}]}
    assert json.dumps(jsonable(data)) == '{"1": [0.5, [0, 1]], "b": [true, {"c": 3}]}'


def test_jsonable_with_finite_writes_nan_and_inf_as_null():
    data = {"a": [np.float64("nan"), math.inf, 1.5], "b": np.float32(-np.inf)}
    assert json.dumps(jsonable(data, finite=True)) == '{"a": [null, null, 1.5], "b": null}'
    assert jsonable([math.nan])[0] != jsonable([math.nan])[0]  # kept without finite
