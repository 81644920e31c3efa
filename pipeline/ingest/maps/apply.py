"""Applying a channel map to a raw log: each rule's sources looked up, transformed and
converted into canonical SI channels, or the reason a channel cannot be filled."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from pipeline.errors import FsidError
from pipeline.ingest.flightdata import CANONICAL_UNITS, Channel
from pipeline.ingest.maps.lookup import lookup, onto, split_source
from pipeline.ingest.maps.rules import UNIT_FACTORS, ChannelMap, ChannelRule
from pipeline.ingest.maps.servo import (
    DEFAULT_TRAVEL_DEG,
    mixed_outputs,
    mixed_surface,
    no_output,
    pwm_deflection,
    servo_number,
    servo_travel,
    torque_surface,
)
from pipeline.ingest.pose import quat_to_euler
from pipeline.ingest.rawlog import RawLog

#: the Euler angles in the order :func:`pipeline.ingest.pose.quat_to_euler` returns them
EULER = ("phi", "theta", "psi")


def _quat_euler(w, x, y, z, comp: str) -> np.ndarray:
    """One Euler angle (``comp``: phi, theta or psi) of the quaternions w, x, y, z (body -> NED)."""
    if comp not in EULER:
        raise FsidError(f"quaternion component '{comp}' unknown; use phi, theta or psi")
    return quat_to_euler(np.column_stack([w, x, y, z]))[EULER.index(comp)]


def apply_rule(raw: RawLog, rule: ChannelRule, travel_deg: float = DEFAULT_TRAVEL_DEG) -> Channel | str:
    """Fill one channel from the raw tables, or return why it cannot be filled.
    ``travel_deg``: a PWM surface's deflection at full servo travel (:func:`servo_travel`)."""
    if rule.scale_param:
        if rule.scale_param not in raw.params:
            return f"no parameter {rule.scale_param} in the log"
        got = _apply_rule(raw, rule, travel_deg)
        if isinstance(got, str):
            return got
        k = float(raw.params[rule.scale_param])
        return Channel(got.t, got.values * k, got.unit, f"{got.source} x {rule.scale_param} ({k:g})")
    return _apply_rule(raw, rule, travel_deg)


def _apply_rule(raw: RawLog, rule: ChannelRule, travel_deg: float = DEFAULT_TRAVEL_DEG) -> Channel | str:
    """One channel by the rule's transform, or from the first of its sources present."""
    if rule.transform in ("quat_wxyz", "quat_xyzw"):
        return _quaternion(raw, rule)
    if rule.transform == "product":
        return _product(raw, rule)
    if rule.transform == "polar":
        return _polar(raw, rule)
    return _first_source(raw, rule, travel_deg)


def _quaternion(raw: RawLog, rule: ChannelRule) -> Channel | str:
    """An Euler angle (``rule.component``) of the quaternion in the rule's 4 sources."""
    if len(rule.sources) != 4:
        return "quaternion transform needs 4 sources"
    got = [lookup(raw, s) for s in rule.sources]
    for g in got:
        if isinstance(g, str):
            return g
    tabs = [g[0] for g in got]
    n = min(len(g[1]) for g in got)
    comps = [g[1][:n] for g in got]
    if rule.transform == "quat_xyzw":
        comps = [comps[3], comps[0], comps[1], comps[2]]
    vals = (_quat_euler(*comps, rule.component or "phi") + rule.offset) * rule.sign
    if rule.component in ("phi", "psi"):
        vals = (vals + np.pi) % (2 * np.pi) - np.pi
    return Channel(
        np.asarray(tabs[0].t[:n], float),
        vals,
        CANONICAL_UNITS.get(rule.name, "rad"),
        f"{rule.transform}({', '.join(rule.sources)}).{rule.component}",
    )


def _product(raw: RawLog, rule: ChannelRule) -> Channel | str:
    """sources[0] x sources[1] (interpolated onto sources[0]); the first alone, said so,
    when the second is missing or ``unless_param`` says it needs none."""
    a = lookup(raw, rule.sources[0])
    if isinstance(a, str):
        return a
    if len(rule.sources) < 2:
        return "product transform needs 2 sources"
    b = lookup(raw, rule.sources[1])
    tab, va = a
    if rule.unless_param and float(raw.params.get(rule.unless_param, 0.0)) != 0.0:
        b = f"log parameter {rule.unless_param} says {rule.sources[0]} needs no factor"
    if isinstance(b, str):  # keep the first factor alone and say so
        vals = rule.scaled(va)
        return Channel(
            np.asarray(tab.t, float),
            vals,
            CANONICAL_UNITS.get(rule.name, rule.unit),
            f"{rule.sources[0]} (without {rule.sources[1]}: {b})",
        )
    f = onto(tab.t, b, rule.sources[1])
    if isinstance(f, str):
        return f
    vals = rule.scaled(va * f)
    return Channel(
        np.asarray(tab.t, float),
        vals,
        CANONICAL_UNITS.get(rule.name, rule.unit),
        f"{rule.sources[0]} x {rule.sources[1]}",
    )


def _polar(raw: RawLog, rule: ChannelRule) -> Channel | str:
    """The speed sources[0] along the course sources[1] [deg]: its north or east component."""
    if len(rule.sources) != 2 or rule.component not in ("north", "east"):
        return "polar transform needs 2 sources (speed, course in deg) and component north or east"
    a = lookup(raw, rule.sources[0])
    if isinstance(a, str):
        return a
    tab, va = a
    b = lookup(raw, rule.sources[1])
    if isinstance(b, str):
        return b
    # the course's cosine and sine interpolated (a course through 360 deg stays whole)
    c, sn = (onto(tab.t, (b[0], fn(np.radians(b[1]))), rule.sources[1]) for fn in (np.cos, np.sin))
    if isinstance(c, str):
        return c
    trig = (c if rule.component == "north" else sn) / np.maximum(np.hypot(c, sn), 1e-9)
    vals = rule.scaled(va * trig)
    return Channel(
        np.asarray(tab.t, float),
        vals,
        CANONICAL_UNITS.get(rule.name, rule.unit),
        f"polar({rule.sources[0]}, {rule.sources[1]}).{rule.component}",
    )


def _first_source(raw: RawLog, rule: ChannelRule, travel_deg: float) -> Channel | str:
    """The channel from the first of the rule's sources the log has (servo outputs, mixed
    or allocated surfaces resolved), or every source's reason joined."""
    reasons = []
    for src in rule.sources_for(raw.params):
        # the servo output whose calibration applies (function or channel of the pwm block)
        n = servo_number(rule, raw.params) if rule.pwm is not None else None
        if "{k}" in src:  # PX4 control surfaces k, weighted by their torque coefficients
            got = torque_surface(raw, rule, src, travel_deg)
            if isinstance(got, Channel):
                return got
            reasons.append(got)
            continue
        if "{n}" in src:  # the source is that output's field
            if n is None:
                mixed = mixed_outputs(rule, raw.params)
                if mixed is not None:
                    got = mixed_surface(raw, rule, src, *mixed, travel_deg)
                    if isinstance(got, Channel):
                        return got
                    reasons.append(got)
                    continue
                reasons.append(no_output(rule))
                continue
            src = src.replace("{n}", str(n))
        unit = rule.unit
        if " " in src.strip():  # "MSG.field unit": a unit for this source only
            src, unit = src.split()[0], src.split()[1]
        negated = src.startswith("-")  # "-MSG.field": this source's opposite (NED down -> up)
        src = src.removeprefix("-")
        got = lookup(raw, src)
        if isinstance(got, str):
            reasons.append(got)
            continue
        tab, raw_v = got
        note = f" [{unit}]" if unit != rule.unit else ""
        if rule.pwm is not None:
            vals, note = pwm_deflection(rule, raw_v * rule.scale + rule.offset, raw.params, n, travel_deg)
            vals = vals * rule.sign
        else:
            vals = -rule.scaled(raw_v, unit) if negated else rule.scaled(raw_v, unit)
        notes = ""
        msg, fld = split_source(src)
        logged = tab.units.get(fld)
        if (
            logged
            and unit in UNIT_FACTORS
            and logged in UNIT_FACTORS
            and UNIT_FACTORS[logged] != UNIT_FACTORS[unit]
            and rule.pwm is None
        ):
            notes = f"the log's unit metadata (FMTU) gives {src} in {logged} but the map reads it as {unit}; check the channel map"
        return Channel(
            np.asarray(tab.t, dtype=np.float64),
            vals,
            CANONICAL_UNITS.get(rule.name, rule.unit),
            ("-" if negated else "") + src + note,
            notes,
        )
    return "; ".join(dict.fromkeys(reasons))


def apply_map(
    raw: RawLog, cmap: ChannelMap, servo_travel_deg: Mapping[str, tuple[float, str]] | None = None
) -> tuple[dict[str, Channel], dict[str, str], dict[str, dict]]:
    """All channels of ``cmap`` that the log can fill, for the others the reason, and for
    the surfaces decoded from servo PWM their deflection at full travel ({"deg", "from"}).
    ``servo_travel_deg``: channel -> (deg, origin) given by the caller (:func:`servo_travel`);
    an assumed travel is also in the channel's notes (a data-quality warning)."""
    chans: dict[str, Channel] = {}
    why: dict[str, str] = {}
    travels: dict[str, dict] = {}
    rules = dict(cmap.rules)
    if cmap.header.get("canonical"):  # every canonical column of every table, SI units
        for tname, tab in raw.tables.items():
            for f in tab.fields:
                if f in CANONICAL_UNITS and f != "t" and f not in rules:
                    rules[f] = ChannelRule(f, [f"{tname}.{f}"], CANONICAL_UNITS[f])
    for name, rule in rules.items():
        surface = rule.pwm is not None and not dict(rule.pwm).get("throttle")
        deg, origin = (
            servo_travel(rule, raw.params, (servo_travel_deg or {}).get(name)) if surface else (DEFAULT_TRAVEL_DEG, "")
        )
        got, used = apply_rule(raw, rule, deg), rule
        if isinstance(got, str) and rule.fallback is not None:
            first, alt = got, apply_rule(raw, rule.fallback, deg)
            if isinstance(alt, str):
                got = f"{first}; fallback {', '.join(rule.fallback.sources)}: {alt}"
            else:
                got, used = alt, rule.fallback
                got.notes = "; ".join(
                    filter(
                        None,
                        [
                            got.notes,
                            (
                                f"from the fallback {got.source} ({', '.join(rule.sources)}: {first})"
                                + (f": {used.derived}" if used.derived else "")
                            ),
                        ],
                    )
                )
        if isinstance(got, str):
            why[name] = got
            continue
        got.derived = used.derived or ""
        if surface:
            travels[name] = {"deg": deg, "from": origin}
            if origin == "assumed":
                got.notes = "; ".join(
                    filter(
                        None,
                        [
                            got.notes,
                            (
                                f"deflection from the servo command with {deg:g} deg at full servo travel assumed "
                                f"(the control derivatives scale with it): give the aircraft TOML's "
                                f"[servos] {name}_travel_deg"
                            ),
                        ],
                    )
                )
        chans[name] = got
    return chans, why, travels
