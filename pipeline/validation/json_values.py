"""JSON-ready values: numpy scalars and arrays to Python, NaN and inf to ``None``.

The validation dict is built from these so that report.json can be written from it
as it is (:func:`json_ready` drops only the numpy ``"arrays"`` the recording plots)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import pandas as pd


def num(x: Any) -> Any:
    """A JSON-ready copy of x: numpy scalars/arrays to Python, NaN/inf to None."""
    if isinstance(x, Mapping):
        return {str(k): num(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [num(v) for v in x]
    if isinstance(x, np.ndarray):
        return [num(v) for v in x.tolist()]
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if x is pd.NA or x is None:
        return None
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(float(x)) else None
    if isinstance(x, complex):
        return [num(x.real), num(x.imag)]
    return x


def json_ready(validation: Mapping[str, Any]) -> dict[str, Any]:
    """The validation dict without ``"arrays"``, every value JSON-serialisable."""
    return num({k: v for k, v in validation.items() if k != "arrays"})


def frame_dict(df: pd.DataFrame) -> dict[str, dict[str, Any]]:
    """{row: {column: value}} of a DataFrame, JSON-ready."""
    return num({str(i): row.to_dict() for i, row in df.iterrows()})
