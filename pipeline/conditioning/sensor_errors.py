"""Sensor errors in the compatibility check's parameter names (``bias_<ch>``,
``scale_<ch>``, ``delay_air``): removing them from a log, those a second flight with the
same sensors shares, and the injected ones of a simulated flight's truth."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from pipeline.conditioning.flight_path_model import INPUTS
from pipeline.ingest.flightdata import Channel, FlightData


def remove_sensor_errors(fd: FlightData, errors: Mapping[str, float], keep_times: bool = False) -> FlightData:
    """A copy of ``fd`` with sensor errors (this module's names: ``bias_<ch>``,
    ``scale_<ch>``, ``delay_air``; missing ones are 0) removed from the measured channels
    (IMU: (x - bias) / (1 + scale); air data also shifted earlier by the delay).

    keep_times : undo the delay by interpolating each air-data channel at t + delay on
        its own sample times (samples whose t + delay lies past the channel's end are
        dropped) instead of moving the time stamps: the channel keeps its sample grid,
        which the estimation's multi-rate frame places slow channels on."""
    v = errors
    out = FlightData(dict(fd.channels), dict(fd.meta), list(fd.segments))
    for ch in INPUTS:
        if ch in fd.channels:
            c = fd.channels[ch]
            vals = (c.values - v.get(f"bias_{ch}", 0.0)) / (1.0 + v.get(f"scale_{ch}", 0.0))
            out.channels[ch] = Channel(c.t, vals, c.unit, c.source + " (compatibility-corrected)")
    tau = float(v.get("delay_air", 0.0))
    for ch in ("V", "alpha", "beta"):
        if ch in fd.channels:
            c = fd.channels[ch]
            vals = (c.values - v.get(f"bias_{ch}", 0.0)) / (1.0 + v.get(f"scale_{ch}", 0.0))
            if keep_times and tau != 0.0 and len(c.t) > 1:
                keep = (c.t + tau >= c.t[0]) & (c.t + tau <= c.t[-1])
                out.channels[ch] = Channel(
                    c.t[keep], np.interp(c.t[keep] + tau, c.t, vals), c.unit, c.source + " (compatibility-corrected)"
                )
                continue
            out.channels[ch] = Channel(c.t - tau, vals, c.unit, c.source + " (compatibility-corrected)")
    out.meta["compatibility"] = {k: float(x) for k, x in v.items()}
    return out


def instrument_errors(applied: Mapping[str, Mapping[str, float]]) -> dict[str, float]:
    """Of a compatibility document's ``applied`` errors, those of the instruments that a
    second flight with the same sensors shares: the scale factors and the air-data delay
    (name -> estimate). Biases are left out: they change with every power-up (the proof of
    match fits its own output biases)."""
    return {n: float(d["estimate"]) for n, d in applied.items() if n.startswith("scale_") or n == "delay_air"}


def truth_errors(truth: Mapping) -> dict[str, float]:
    """Injected sensor errors of a ``truth.json`` document in this module's parameter names."""
    s = truth.get("sensors", {})
    out: dict[str, float] = {}
    imu, air = s.get("imu", {}), s.get("airdata", {})
    for ch in INPUTS:
        out[f"bias_{ch}"] = float(imu.get("bias", {}).get(ch, 0.0))
        out[f"scale_{ch}"] = float(imu.get("scale_factor", {}).get(ch, 0.0))
    for ch in ("V", "alpha", "beta"):
        out[f"bias_{ch}"] = float(air.get("bias", {}).get(ch, 0.0))
        out[f"scale_{ch}"] = float(air.get("scale_factor", {}).get(ch, 0.0))
    out["delay_air"] = float(air.get("delay_s", 0.0))
    return out
