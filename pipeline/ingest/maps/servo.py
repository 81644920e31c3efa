"""Control surfaces from servo outputs: PWM calibration (SERVOn_* parameters), mixed
servos (elevons, V-tail), PX4's allocated surface commands, and the deflection at full
servo travel (the map format: :mod:`pipeline.ingest.maps.rules`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from pipeline.ingest.flightdata import CANONICAL_UNITS, Channel
from pipeline.ingest.maps.lookup import lookup
from pipeline.ingest.maps.rules import ChannelRule
from pipeline.ingest.rawlog import RawLog


def _param(params: dict, value, default: float) -> float:
    if isinstance(value, str):
        return float(params.get(value, default))
    if value is None:
        return default
    return float(value)


def function_output(params: Mapping[str, float], fn: float) -> int | None:
    """The first servo output n with ``SERVOn_FUNCTION`` = fn, or None."""
    for k in range(1, 33):
        if params.get(f"SERVO{k}_FUNCTION") == float(fn):
            return k
    return None


def servo_number(rule: ChannelRule, params: dict) -> int | None:
    """The servo output of a PWM rule: the one whose SERVOn_FUNCTION is the rule's
    ``function``; the rule's default ``channel`` only when the log has no SERVOn_FUNCTION
    parameters at all (with them, a missing function means no such output: on a tilt-rotor
    output 4 is a motor tilt, on a flying wing output 2 an elevon)."""
    cfg = dict(rule.pwm or {})
    fn = cfg.get("function")
    if fn is not None:
        n = function_output(params, fn)
        if n is not None or any(k.startswith("SERVO") and k.endswith("_FUNCTION") for k in params):
            return n
    n = cfg.get("channel")
    return int(n) if n is not None else None


def no_output(rule: ChannelRule) -> str:
    """Why a PWM rule has no servo output: the functions the log's SERVOn_FUNCTION lacks."""
    cfg = dict(rule.pwm or {})
    if cfg.get("function") is None:
        return f"no servo output configured for {rule.name}"
    wanted = [f"{cfg['function']:g}"] + ["/".join(f"{f:g}" for f in m.get("functions", ())) for m in cfg.get("mix", ())]
    return f"no servo output configured for {rule.name} (no SERVOn_FUNCTION = {' or '.join(wanted)})"


def mixed_outputs(rule: ChannelRule, params: Mapping[str, float]) -> tuple[list[int], list[float], list[float]] | None:
    """(outputs, functions, weights) of the first of the rule's ``pwm.mix`` entries whose
    every function is assigned to an output (SERVOn_FUNCTION), or None."""
    for mix in dict(rule.pwm or {}).get("mix", ()):
        fns, ws = list(mix.get("functions", ())), list(mix.get("weights", ()))
        ns = [function_output(params, f) for f in fns]
        if fns and len(ws) == len(fns) and all(n is not None for n in ns):
            return ns, fns, ws
    return None


#: deflection (deg) at full servo travel assumed when neither the caller, the map nor the log
#: gives it
DEFAULT_TRAVEL_DEG = 30.0


def servo_travel(
    rule: ChannelRule, params: Mapping[str, float], given: tuple[float, str] | None = None
) -> tuple[float, str]:
    """(deg, where it came from) of a PWM surface channel's deflection at full servo travel:
    ``given`` (deg, origin), else the map's ``travel_deg`` (a number; or a log parameter's
    name, used when the log has it), else DEFAULT_TRAVEL_DEG with origin "assumed"."""
    if given is not None:
        return float(given[0]), given[1]
    v = dict(rule.pwm or {}).get("travel_deg")
    if isinstance(v, str):
        if v in params:
            return float(params[v]), f"log parameter {v}"
    elif v is not None:
        return float(v), "channel map"
    return DEFAULT_TRAVEL_DEG, "assumed"


def pwm_deflection(
    rule: ChannelRule, pwm: np.ndarray, params: dict, n: int | None, travel_deg: float = DEFAULT_TRAVEL_DEG
) -> tuple[np.ndarray, str]:
    """Servo output n's pulses (us) -> deflection (rad) or throttle (0..1), and the note of
    its calibration."""
    cfg = dict(rule.pwm or {})
    if cfg.get("normalised"):  # a -1..1 surface command (PX4 actuator controls)
        return pwm * np.radians(travel_deg), ""
    note = ""
    if n is not None:
        pre = f"SERVO{n}_"
        lo = _param(params, cfg.get("min", pre + "MIN"), 1100.0)
        hi = _param(params, cfg.get("max", pre + "MAX"), 1900.0)
        tr = _param(params, cfg.get("trim", pre + "TRIM"), 1500.0)
        rev = _param(params, cfg.get("reversed", pre + "REVERSED"), 0.0)
        note = f" (SERVO{n}: min {lo:g} trim {tr:g} max {hi:g}{' reversed' if rev else ''})"
    else:
        lo, hi, tr, rev = (
            float(cfg.get("min", 1100)),
            float(cfg.get("max", 1900)),
            float(cfg.get("trim", 1500)),
            float(cfg.get("reversed", 0)),
        )
    if cfg.get("throttle"):
        x = (pwm - lo) / max(hi - lo, 1e-9)
        return np.clip(x, 0.0, 1.0), note
    up = max(hi - tr, 1e-9)
    dn = max(tr - lo, 1e-9)
    x = np.where(pwm >= tr, (pwm - tr) / up, (pwm - tr) / dn)
    if rev:
        x = -x
    return x * np.radians(travel_deg), note


#: PX4 control-allocation torque axes of a surface channel (``pwm.torque``)
TORQUE_AXES = ("R", "P", "Y")


def torque_surface(raw: RawLog, rule: ChannelRule, src: str, travel_deg: float) -> Channel | str:
    """A surface channel from PX4's allocated servo commands (``actuator_servos.control[k]``,
    -1..1, source written with ``{k}``): the control surfaces k = 0..CA_SV_CS_COUNT-1
    weighted by their torque coefficients on the rule's axis (``pwm.torque``:
    CA_SV_CS{k}_TRQ_R / _P / _Y) over the sum of the coefficients' magnitudes - one
    elevator gives its own command, two elevons their mean, two ailerons half their
    difference, as the torque the allocation meant - times the travel, then the sign."""
    axis = str(dict(rule.pwm or {}).get("torque", "")).upper()
    if axis not in TORQUE_AXES:
        return f"pwm.torque must be one of {', '.join(TORQUE_AXES)}, not {axis!r}"
    params = raw.params
    if "CA_SV_CS_COUNT" not in params:
        return "no CA_SV_CS_COUNT parameter (no PX4 control allocation)"
    ks = range(int(params["CA_SV_CS_COUNT"]))
    trq = np.array([float(params.get(f"CA_SV_CS{k}_TRQ_{axis}", 0.0)) for k in ks])
    if not np.any(trq != 0.0):
        return f"no control surface with a torque on {axis} (CA_SV_CS*_TRQ_{axis} all 0)"
    w = trq / np.sum(np.abs(trq))
    used = [(k, wk) for k, wk in zip(ks, w) if wk != 0.0]
    got = _weighted_sum(
        raw, [(src.replace("{k}", str(k)), wk, k) for k, wk in used], lambda k, v: (v * rule.scale + rule.offset, "")
    )
    if isinstance(got, str):
        return got
    t0, total, _ = got
    name = src.split(".")[0]
    return Channel(
        t0,
        total * np.radians(travel_deg) * rule.sign,
        CANONICAL_UNITS.get(rule.name, "rad"),
        f"{name} by CA_SV_CS*_TRQ_{axis}: " + " ".join(f"{wk:+.3g} x control[{k}]" for k, wk in used),
    )


def mixed_surface(
    raw: RawLog,
    rule: ChannelRule,
    src: str,
    outputs: Sequence[int],
    functions: Sequence[float],
    weights: Sequence[float],
    travel_deg: float,
) -> Channel | str:
    """A surface channel from mixed servos (``pwm.mix``): sum of weight x deflection of each
    output, each calibrated with its own SERVOn_MIN/MAX/TRIM/REVERSED and the channel's
    travel, on the first output's time base; then the rule's sign."""
    srcs = [src.split()[0].replace("{n}", str(n)) for n in outputs]
    got = _weighted_sum(
        raw,
        list(zip(srcs, weights, outputs)),
        lambda n, v: pwm_deflection(rule, v * rule.scale + rule.offset, raw.params, n, travel_deg),
    )
    if isinstance(got, str):
        return got
    t0, total, notes = got
    fns = "/".join(f"{f:g}" for f in functions)
    return Channel(
        t0,
        total * rule.sign,
        CANONICAL_UNITS.get(rule.name, "rad"),
        f"mix of SERVOn_FUNCTION {fns}: "
        + " ".join(f"{w:+g} x {s_}{note}" for s_, w, note in zip(srcs, weights, notes)),
    )


def _weighted_sum(
    raw: RawLog, terms: Sequence[tuple[str, float, object]], convert
) -> tuple[np.ndarray, np.ndarray, list[str]] | str:
    """(t, sum of weight x values, notes) over ``terms`` (source, weight, key), each
    source's values passed through ``convert(key, values) -> (values, note)``, on the first
    source's time base (the others interpolated onto it); or why a source is missing."""
    total, notes, t0 = None, [], None
    for source, w, key in terms:
        got = lookup(raw, source)
        if isinstance(got, str):
            return got
        tab, raw_v = got
        vals, note = convert(key, raw_v)
        t = np.asarray(tab.t, dtype=np.float64)
        if t0 is None:
            t0, total = t, np.zeros(len(t))
        elif t.shape != t0.shape or not np.array_equal(t, t0):
            vals = np.interp(t0, t, vals)
        total = total + w * vals
        notes.append(note)
    return t0, total, notes
