"""Small text and JSON helpers shared by the library, the agents and the studies.

:func:`is_number` is the one test of "a real number, not a boolean"; :func:`value_text`
shows a value as error messages print it; :func:`number_text` formats a number for a
message, a table or a report (exact, significant digits or decimal places);
:func:`jsonable` turns NumPy values inside dicts and lists into plain Python for JSON.
"""

from __future__ import annotations

import math
import numbers
from typing import Any

import numpy as np

__all__ = ["is_number", "jsonable", "number_text", "value_text"]


def is_number(value: Any, *, finite: bool = False) -> bool:
    """``value`` is a real number and not a boolean (Python's or NumPy's); with
    ``finite``, also neither NaN nor infinite."""
    if not isinstance(value, numbers.Real) or isinstance(value, (bool, np.bool_)):
        return False
    return not finite or math.isfinite(float(value))


def value_text(value: Any) -> str:
    """A value as error messages print it: -3.0, 20, 'abc', nan, inf."""
    if isinstance(value, numbers.Integral) and not isinstance(value, (bool, np.bool_)):
        return str(int(value))
    if is_number(value):
        return repr(float(value))
    return repr(value)


def number_text(
    value: Any,
    digits: int | None = None,
    *,
    fixed: bool = False,
    missing: str = "-",
    not_finite: str | None = None,
    grouped_from: float = math.inf,
) -> str:
    """A number as short text.

    ``digits`` None: the exact ``repr(float(value))``; else ``digits`` significant digits
    (``fixed``: ``digits`` decimal places). None gives ``missing``; NaN and infinities
    give ``not_finite`` where it is given; a magnitude of at least ``grouped_from`` is
    written as a whole number with thousands separators (``12,345``); text passes as is.
    """
    if isinstance(value, str):
        return value
    if value is None:
        return missing
    if not_finite is not None and isinstance(value, float) and not math.isfinite(value):
        return not_finite
    if digits is None:
        return repr(float(value))
    if abs(value) >= grouped_from:
        return f"{value:,.0f}"
    return f"{value:.{digits}{'f' if fixed else 'g'}}"


def jsonable(value: Any, *, finite: bool = False) -> Any:
    """``value`` with dict keys as strings, tuples and arrays as lists and NumPy scalars
    as Python values, so that ``json.dumps`` takes it; with ``finite``, NaN and infinities
    become None (strict JSON)."""
    if isinstance(value, dict):
        return {str(k): jsonable(v, finite=finite) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v, finite=finite) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist(), finite=finite)
    if isinstance(value, np.generic):
        value = value.item()
    if finite and isinstance(value, float) and not math.isfinite(value):
        return None
    return value
