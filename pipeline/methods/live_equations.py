"""Identification while flying: frequency-domain equation error per axis, updated sample by
sample on the samples' own time stamps (Morelli, "Real-time parameter estimation in the
frequency domain", J. Guidance 23(5), 2000).

Each equation is a force or moment balance divided by the reference area and length, with
the dynamic pressure inside the regressors, so that its parameters are the nondimensional
derivatives even while the airspeed wanders::

    Cm:  Iyy q' / (S c)            = qbar [1, alpha, q c/2V, de] . [Cm0, Cmalpha, Cmq, Cmde]
    CL:  m (ax sin a - az cos a) / S = qbar [1, alpha, q c/2V, de] . [CL0, CLalpha, CLq, CLde]
    Cl:  (Ixx p' - Ixz r') / (S b) = qbar [1, beta, p b/2V, r b/2V, da, dr] . [Cl0, Clbeta, ...]
    Cn:  (Izz r' - Ixz p') / (S b) = the same regressors . [Cn0, Cnbeta, ...]
    CY:  m ay / S                  = the same regressors . [CY0, CYbeta, ...]

(the thrust left out of CL, the inertia coupling terms of the moments too: small in the
maneuvers' band; the air-data angles moved from the vane to the CG, the accelerations left at
the IMU: moving them needs the angular accelerations, which are never differentiated here). The rates' derivatives are never differentiated: their transforms are jw
times the rate's plus the record's end terms
(:class:`estimators.FourierRegression` with ``response_derivative``). A row is formed at each
sample of the body rates, the other channels held at their latest sample (what a receiver
knows at that moment); rows are final once every channel has a sample after them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from estimators import EstimationError, FourierRegression
from pipeline.ingest.constants import isa_density
from pipeline.ingest.flightdata import FlightData

#: the band (Hz) and the number of frequencies the transforms are updated at
BAND_HZ = (0.1, 2.0)
N_FREQUENCIES = 40
#: a derivative is "enough" once its std falls below this share of its magnitude
TARGET_REL_STD = 0.1


@dataclass(frozen=True)
class Equation:
    """One balance of the module docstring: its name, the channels it needs, its parameter
    names (in the regressors' order) and whether the response is differentiated."""

    name: str
    channels: tuple[str, ...]
    parameters: tuple[str, ...]
    derivative: bool


_LON = ("alpha", "q", "de", "V")
_LAT = ("beta", "p", "r", "da", "dr", "V")
EQUATIONS = (
    Equation("Cm", _LON, ("Cm0", "Cmalpha", "Cmq", "Cmde"), True),
    Equation("CL", (*_LON, "ax", "az"), ("CL0", "CLalpha", "CLq", "CLde"), False),
    Equation("Cl", _LAT, tuple(f"Cl{s}" for s in ("0", "beta", "p", "r", "da", "dr")), True),
    Equation("Cn", _LAT, tuple(f"Cn{s}" for s in ("0", "beta", "p", "r", "da", "dr")), True),
    Equation("CY", (*_LAT, "ay"), tuple(f"CY{s}" for s in ("0", "beta", "p", "r", "da", "dr")), False),
)


def held(fd: FlightData, name: str, t: np.ndarray) -> np.ndarray:
    """Channel ``name`` at times ``t`` held at its latest sample at or before each (NaN
    before its first)."""
    ch = fd[name]
    i = np.searchsorted(ch.t, t, side="right") - 1
    out = np.full(t.size, np.nan)
    ok = i >= 0
    out[ok] = np.asarray(ch.values, dtype=float)[i[ok]]
    return out


def equation_rows(eq: Equation, fd: FlightData, c: Mapping[str, float], t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(X (N, k), y (N,)) of equation ``eq`` at the rate samples ``t`` (module docstring);
    ``c``: m, S, cbar, b, Ixx, Iyy, Izz, Ixz."""
    v = {n: held(fd, n, t) for n in eq.channels}
    if "p" in v or "q" in v:
        v.update(_at_cg(fd, c, t, v))
    rho = isa_density(held(fd, "h", t)) if "h" in fd else np.full(t.size, float(isa_density(0.0)))
    rho = np.where(np.isfinite(rho), rho, float(isa_density(0.0)))
    V = v["V"]
    qbar = 0.5 * rho * V**2
    if eq.name in ("Cm", "CL"):
        X = qbar[:, None] * np.column_stack([np.ones(t.size), v["alpha"], v["q"] * c["cbar"] / (2 * V), v["de"]])
        if eq.name == "Cm":
            y = c["Iyy"] * v["q"] / (c["S"] * c["cbar"])
        else:
            a = v["alpha"]
            y = c["m"] * (v["ax"] * np.sin(a) - v["az"] * np.cos(a)) / c["S"]
        return X, y
    k = c["b"] / (2 * V)
    X = qbar[:, None] * np.column_stack([np.ones(t.size), v["beta"], v["p"] * k, v["r"] * k, v["da"], v["dr"]])
    if eq.name == "Cl":
        y = (c["Ixx"] * v["p"] - c["Ixz"] * v["r"]) / (c["S"] * c["b"])
    elif eq.name == "Cn":
        y = (c["Izz"] * v["r"] - c["Ixz"] * v["p"]) / (c["S"] * c["b"])
    else:
        y = c["m"] * v["ay"] / c["S"]
    return X, y


def _at_cg(fd: FlightData, c: Mapping[str, float], t: np.ndarray, v: dict) -> dict[str, np.ndarray]:
    """The air-data angles moved from the vane to the CG (the inverse of the vane's
    reading alpha - q x_vane / V, beta + (r x_vane - p z_vane) / V): left at the vane, the
    rate terms would be booked on the damping derivatives."""
    x, z = c.get("x_vane", 0.0), c.get("z_vane", 0.0)
    out = {}
    V = v["V"]
    if "alpha" in v and x:
        out["alpha"] = v["alpha"] + v["q"] * x / V
    if "beta" in v and (x or z):
        out["beta"] = v["beta"] - (v["r"] * x - v["p"] * z) / V
    return out


def rate_times(fd: FlightData, eq: Equation) -> np.ndarray:
    """The times of the equation's rows: the samples of its body rate (q, else p)."""
    return np.asarray(fd["q" if "q" in eq.channels else "p"].t, dtype=float)


def settled_until(fd: FlightData, eq: Equation) -> float:
    """The time up to which the equation's rows are final: every channel it reads has a
    sample at or after it."""
    return min(float(fd[n].t[-1]) for n in eq.channels)


@dataclass
class LiveEquation:
    """One equation's recursive regression and its state."""

    eq: Equation
    reg: FourierRegression
    t_first: float = np.nan
    t_done: float = -np.inf
    rows: int = 0
    enough: dict[str, float] = field(default_factory=dict)  #: parameter -> time it became enough

    def add(self, t: np.ndarray, X: np.ndarray, y: np.ndarray) -> None:
        """Add the finite rows after t_done, in time order (a row at the time of the one
        before it, two samples the ingest could not set apart, is left out)."""
        ok = (t > self.t_done) & np.all(np.isfinite(X), axis=1) & np.isfinite(y)
        before = np.r_[self.t_done, np.maximum.accumulate(np.where(ok, t, -np.inf))[:-1]]
        ok &= t > before
        if ok.any():
            if not np.isfinite(self.t_first):
                self.t_first = float(t[ok][0])
            self.reg.update_many(X[ok], y[ok], t[ok])
            self.t_done = float(t[ok][-1])
            self.rows += int(ok.sum())

    def estimate(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(theta, std) of the rows so far; None before they determine it. A record of T s
        resolves frequencies 1/T apart: while the band holds fewer than n_f of those, its
        transforms are not independent and the regression's covariance is scaled up by
        n_f / (band width x T), so that an early std is not too small."""
        k = len(self.eq.parameters)
        if self.rows < 4 * k:
            return None
        try:
            with np.errstate(all="ignore"):
                theta, cov = self.reg.estimate()
        except (EstimationError, np.linalg.LinAlgError, ValueError, ArithmeticError):  # singular early on
            return None
        f = self.reg.frequencies
        independent = (f[-1] - f[0]) * (self.t_done - self.t_first)
        cov = cov * max(1.0, f.size / max(independent, 1e-9))
        std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        return (theta, std) if np.all(np.isfinite(theta)) and np.all(np.isfinite(std)) else None


class LiveIdentification:
    """Every equation whose channels the flight data have, updated from FlightData read
    again as the stream grows (:meth:`update`), and their estimates (:meth:`estimates`)."""

    def __init__(
        self,
        constants: Mapping[str, float],
        band: tuple[float, float] = BAND_HZ,
        n_frequencies: int = N_FREQUENCIES,
        target: float = TARGET_REL_STD,
    ) -> None:
        self.c = dict(constants)
        self.f = np.linspace(band[0], band[1], n_frequencies)
        self.target = float(target)
        self.live: dict[str, LiveEquation] = {}

    def update(self, fd: FlightData, final: bool = False, until: float = np.inf) -> int:
        """Add the rows up to ``until`` (s) that are final in ``fd`` (every row when
        ``final``: the stream ended); returns how many were added."""
        added = 0
        for eq in EQUATIONS:
            if not all(n in fd and len(fd[n].t) for n in eq.channels):
                continue
            le = self.live.get(eq.name)
            if le is None:
                reg = FourierRegression(
                    list(eq.parameters), frequencies=self.f, detrend="none", response_derivative=eq.derivative
                )
                reg.start(None, len(eq.parameters))
                le = self.live[eq.name] = LiveEquation(eq, reg)
            t = rate_times(fd, eq)
            t = t[(t > le.t_done) & (t <= until)]
            if not final:
                t = t[t <= settled_until(fd, eq)]
            if t.size == 0:
                continue
            before = le.rows
            X, y = equation_rows(eq, fd, self.c, t)
            le.add(t, X, y)
            added += le.rows - before
        return added

    def estimates(self, t_now: float) -> dict[str, dict[str, dict[str, float]]]:
        """Equation -> parameter -> {value, std, rel_std, enough (time or NaN)}; the first
        time a derivative's relative std falls below the target is kept."""
        out = {}
        for name, le in self.live.items():
            got = le.estimate()
            if got is None:
                continue
            theta, std = got
            d = {}
            for p, v, s in zip(le.eq.parameters, theta, std):
                rel = float(s / abs(v)) if v != 0 else float("inf")
                if not p.endswith("0") and rel < self.target and p not in le.enough:
                    le.enough[p] = t_now
                d[p] = {"value": float(v), "std": float(s), "rel_std": rel, "enough": le.enough.get(p, float("nan"))}
            out[name] = d
        return out


def regression_constants(ac) -> dict[str, float]:
    """The constants the equations use, from aircraft constants (with the air-data vane's
    position from the CG, m)."""
    out = {k: float(getattr(ac, k)) for k in ("S", "cbar", "b", "Ixx", "Iyy", "Izz", "Ixz")}
    vane = getattr(ac, "airdata", None) or (0.0, 0.0, 0.0)
    return out | {"m": float(ac.mass), "x_vane": float(vane[0]), "z_vane": float(vane[2])}


def equations_for(names: Sequence[str] | None) -> tuple[Equation, ...]:
    """The equations named (all by default)."""
    return EQUATIONS if not names else tuple(e for e in EQUATIONS if e.name in names)
