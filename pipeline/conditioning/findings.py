"""The result type of every data check: :class:`Finding` and its three levels.

One module of its own so that the checks of :mod:`.checks` and those they call
(:mod:`.kinematics`) share it without importing each other.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

PASS, WARN, FAIL = "pass", "warn", "fail"


@dataclass
class Finding:
    """One check result. ``t0``/``t1`` [s] on the log's time base (None: whole file)."""

    status: str
    check: str
    channel: str | None
    message: str
    t0: float | None = None
    t1: float | None = None
    value: float | None = None

    def as_dict(self) -> dict:
        d = asdict(self)
        for k in ("t0", "t1", "value"):
            if d[k] is not None:
                d[k] = float(d[k]) if np.isfinite(d[k]) else None
        return d
