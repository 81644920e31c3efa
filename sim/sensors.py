"""Sensor models: IMU, air-data boom, attitude, baro altitude, surface positions, GPS.

Each sensor samples the noise-free truth at its own rate. For a sample at time t_k the
sensor reports (1 + scale) * x(t_k - delay) + bias + noise * N(0, 1), rounded to the
quantisation step when one is given. x includes the mounting-position terms:

* IMU at r (body axes, m, from the CG): a = a_cg + dw/dt x r + w x (w x r); gyros see
  the inertial body rates p, q, r.
* air-data boom at r: v_boom = (u, v, w) + w x r with (u, v, w) air-relative body
  velocity and w = (p, q, r); V, alpha = atan2(w_b, u_b), beta = asin(v_b / V).

Scenario keys per sensor (``[sensors.<name>]``): ``rate_hz``, ``delay_s``, ``position_m``
(imu, airdata) and for every channel group g: ``g_noise_<unit>`` (1-sigma),
``g_bias_<unit>``, ``g_scale`` (fraction, 0.02 = +2 %), ``g_quant_<unit>`` (0 = none);
each takes one number or one per channel. Defaults are small-UAV/light-aircraft values
(MEMS IMU with vibration, 16-bit ADCs, pitot-static and vane boom, EKF attitude).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

D2R = np.pi / 180.0


@dataclass(frozen=True)
class Group:
    channels: tuple[str, ...]
    unit: str  #: unit suffix used in scenario keys
    si: float  #: factor from the scenario unit to SI
    noise: float  #: default 1-sigma noise in the scenario unit
    quant: float  #: default quantisation in the scenario unit


#: sensor -> (default rate Hz or None = scenario rate, has position, groups)
_SENSORS: dict[str, tuple[float | None, bool, dict[str, Group]]] = {
    "imu": (
        None,
        True,
        {
            "accel": Group(("ax", "ay", "az"), "mps2", 1.0, 0.05, 0.0024),
            "gyro": Group(("p", "q", "r"), "dps", D2R, 0.1, 0.061),
        },
    ),
    "airdata": (
        50.0,
        True,
        {"airspeed": Group(("V",), "mps", 1.0, 0.3, 0.01), "vane": Group(("alpha", "beta"), "deg", D2R, 0.2, 0.0)},
    ),
    "attitude": (50.0, False, {"angle": Group(("phi", "theta", "psi"), "deg", D2R, 0.1, 0.0)}),
    "baro": (20.0, False, {"alt": Group(("h",), "m", 1.0, 0.3, 0.01)}),
    "surfaces": (
        None,
        False,
        {
            "defl": Group(("de", "da", "dr"), "deg", D2R, 0.05, 0.0),
            "throttle": Group(("throttle",), "frac", 1.0, 0.0, 0.0),
        },
    ),
    "gps": (
        10.0,
        False,
        {"vel": Group(("vn", "ve", "vd"), "mps", 1.0, 0.1, 0.0), "alt": Group(("h",), "m", 1.0, 1.0, 0.0)},
    ),
}


def _keys(name: str) -> dict[str, object]:
    rate, pos, groups = _SENSORS[name]
    keys: dict[str, object] = {"rate_hz": rate, "delay_s": 0.0}
    if pos:
        keys["position_m"] = [0.0, 0.0, 0.0]
    for g, grp in groups.items():
        keys[f"{g}_noise_{grp.unit}"] = grp.noise
        keys[f"{g}_bias_{grp.unit}"] = 0.0
        keys[f"{g}_scale"] = 0.0
        keys[f"{g}_quant_{grp.unit}"] = grp.quant
    return keys


#: sensor name -> {scenario key: default}
SENSOR_SCHEMA: dict[str, dict[str, object]] = {n: _keys(n) for n in _SENSORS}


@dataclass(frozen=True)
class SensorSpec:
    """Error model of one sensor, SI units; arrays have one entry per channel."""

    name: str
    channels: tuple[str, ...]
    units: tuple[str, ...]  #: SI unit of each channel
    rate_hz: float
    delay: float  #: s
    position: np.ndarray  #: (3,) body axes from the CG, m
    noise: np.ndarray  #: 1-sigma white noise
    bias: np.ndarray
    scale: np.ndarray  #: scale-factor error, fraction
    quant: np.ndarray  #: quantisation step (0 = none)

    def to_dict(self) -> dict:
        return {
            "channels": list(self.channels),
            "units": list(self.units),
            "rate_hz": self.rate_hz,
            "delay_s": self.delay,
            "position_m": self.position.tolist(),
            "noise_std": dict(zip(self.channels, self.noise.tolist())),
            "bias": dict(zip(self.channels, self.bias.tolist())),
            "scale_factor": dict(zip(self.channels, self.scale.tolist())),
            "quantisation": dict(zip(self.channels, self.quant.tolist())),
        }


_SI_UNIT = {"mps2": "m/s^2", "dps": "rad/s", "mps": "m/s", "deg": "rad", "m": "m", "frac": "-"}


def sensor_spec(name: str, sec, sim_rate: float) -> SensorSpec:
    """Build a SensorSpec from a scenario section (``sim.scenario._Section``)."""
    rate_default, has_pos, groups = _SENSORS[name]
    rate = sec.num("rate_hz", rate_default or sim_rate, positive=True, hi=sim_rate)
    chans, units, noise, bias, scale, quant = [], [], [], [], [], []

    def vec(key: str, default: float, n: int, factor: float) -> list[float]:
        v = sec.t.get(key, default)
        if isinstance(v, list):
            if len(v) != n or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v):
                raise sec.fail(key, f"must be one number or a list of {n} numbers")
            return [float(x) * factor for x in v]
        return [sec.num(key, default) * factor] * n

    for g, grp in groups.items():
        n = len(grp.channels)
        chans += grp.channels
        units += [_SI_UNIT[grp.unit]] * n
        noise += vec(f"{g}_noise_{grp.unit}", grp.noise, n, grp.si)
        bias += vec(f"{g}_bias_{grp.unit}", 0.0, n, grp.si)
        scale += vec(f"{g}_scale", 0.0, n, 1.0)
        quant += vec(f"{g}_quant_{grp.unit}", grp.quant, n, grp.si)
    if min(noise) < 0 or min(quant) < 0:
        raise sec.fail("", "noise and quantisation must be >= 0")
    pos = vec("position_m", 0.0, 3, 1.0) if has_pos else [0.0, 0.0, 0.0]
    return SensorSpec(
        name=name,
        channels=tuple(chans),
        units=tuple(units),
        rate_hz=rate,
        delay=sec.num("delay_s", 0.0, lo=0.0, hi=1.0),
        position=np.asarray(pos),
        noise=np.asarray(noise),
        bias=np.asarray(bias),
        scale=np.asarray(scale),
        quant=np.asarray(quant),
    )


def lever_arm_signals(truth: pd.DataFrame, spec: SensorSpec) -> dict[str, np.ndarray]:
    """Noise-free signals each channel of ``spec`` sees at its mounting position, on the
    truth time grid: dict channel -> array (N,)."""
    x, y, z = spec.position
    d = {c: truth[c].to_numpy() for c in spec.channels if c in truth}
    if spec.name == "imu":
        p, q, r = (truth[c].to_numpy() for c in ("p", "q", "r"))
        pd_, qd, rd = (truth[c].to_numpy() for c in ("pdot", "qdot", "rdot"))
        d["ax"] = truth["ax"].to_numpy() + (qd * z - rd * y) + (q * (p * y - q * x) - r * (r * x - p * z))
        d["ay"] = truth["ay"].to_numpy() + (rd * x - pd_ * z) + (r * (q * z - r * y) - p * (p * y - q * x))
        d["az"] = truth["az"].to_numpy() + (pd_ * y - qd * x) + (p * (r * x - p * z) - q * (q * z - r * y))
    elif spec.name == "airdata":
        p, q, r = (truth[c].to_numpy() for c in ("p", "q", "r"))
        ub = truth["u"].to_numpy() + q * z - r * y
        vb = truth["v"].to_numpy() + r * x - p * z
        wb = truth["w"].to_numpy() + p * y - q * x
        Vb = np.sqrt(ub**2 + vb**2 + wb**2)
        d["V"], d["alpha"], d["beta"] = Vb, np.arctan2(wb, ub), np.arcsin(vb / Vb)
    return d


def sample_sensor(truth: pd.DataFrame, spec: SensorSpec, rng: np.random.Generator, duration: float) -> pd.DataFrame:
    """Measured table of one sensor: column t (s, its own rate) then its channels (SI)."""
    n = int(np.floor(duration * spec.rate_hz + 1e-9)) + 1
    ts = np.arange(n) / spec.rate_hz
    src = lever_arm_signals(truth, spec)
    tt = truth["t"].to_numpy()
    out = {"t": ts}
    noise = rng.standard_normal((n, len(spec.channels)))
    for i, c in enumerate(spec.channels):
        sig = src[c]
        if c == "psi":  # interpolate a continuous heading, wrap afterwards
            sig = np.unwrap(sig)
        x = np.interp(np.maximum(ts - spec.delay, tt[0]), tt, sig)
        x = (1.0 + spec.scale[i]) * x + spec.bias[i] + spec.noise[i] * noise[:, i]
        if spec.quant[i] > 0:
            x = np.round(x / spec.quant[i]) * spec.quant[i]
        if c == "psi":
            x = np.angle(np.exp(1j * x))
        out[c] = x
    return pd.DataFrame(out)


def default_noise_si() -> dict[str, float]:
    """Channel -> the default 1-sigma white noise of its simulated sensor, SI units (rad,
    rad/s, m/s, m/s^2): what a flight is assumed to measure with when nothing better is known
    (an input design's predicted accuracy)."""
    out: dict[str, float] = {}
    for _, _, groups in _SENSORS.values():
        for grp in groups.values():
            for c in grp.channels:
                out.setdefault(c, grp.noise * grp.si)  # the first sensor of a channel (baro before GPS)
    return out
