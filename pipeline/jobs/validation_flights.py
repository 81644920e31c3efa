"""What a fit is proved on: the last maneuver of each axis held out of the fitted flight,
or every maneuver of one or more validation flights (the fitted flight then fitted whole)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Any

from pipeline.jobs.progress import counted
from pipeline.problems import Problem

#: prefix of the proof-of-match segments taken from a validation flight
VALIDATION_PREFIX = "validation flight: "


def validation_flights(validation: Any) -> list:
    """A job's validation flights as a list: None -> none; one flight (a FlightData, a
    path) -> [it]; a list or tuple of them as it is."""
    if validation is None:
        return []
    return list(validation) if isinstance(validation, (list, tuple)) else [validation]


def hold_out_count(validation: Sequence[Any], fit_all: bool | None) -> int:
    """Maneuvers per axis held out of the fitted flight for the proof of match: none when
    there is a validation flight (``validation``: the list of them; or ``fit_all``: the
    refits of such a run), else one."""
    return 0 if (bool(validation) if fit_all is None else fit_all) else 1


def validation_prefix(k: int, n: int) -> str:
    """Name prefix of the proof-of-match segments of validation flight k (0-based) of n:
    VALIDATION_PREFIX for a single flight, "validation flight <k+1>: " for several."""
    return VALIDATION_PREFIX if n == 1 else f"validation flight {k + 1}: "


def with_validation_flight(
    pb: Problem, vals: Sequence[Problem], calm: bool, numbers: Sequence[int] | None = None, n_flights: int | None = None
) -> Problem:
    """``pb`` with the maneuvers of ``vals`` (the same axis and model built on each
    validation flight, nothing held out there) as its held-out segments, named
    :func:`validation_prefix` + maneuver; ``numbers``: each problem's flight (0-based, of
    ``n_flights``; default: the order given); ``calm``: the flights are known to be in calm
    air (a simulated one)."""
    numbers = list(range(len(vals))) if numbers is None else list(numbers)
    total = len(vals) if n_flights is None else n_flights
    segs, specs, parts, times = [], [], [], []
    for k, val in zip(numbers, vals):
        pre = validation_prefix(k, total)
        mine = [replace(sg, name=pre + sg.name) for sg in val.fit + val.held_out]
        segs += mine
        times += [val.step_times] * len(mine)
        specs += list(val.specs) + list(val.held_specs)
        parts.append(("" if total == 1 else f"flight {k + 1}: ") + ", ".join(sg.name[len(pre) :] for sg in mine))
    where = "the validation flight's" if total == 1 else f"{total} validation flights'"
    note = (
        f"proof of match on {where} {counted(len(segs), 'maneuver')} "
        f"({'; '.join(parts)})" + ("; flown in calm air" if calm else "") + "; every maneuver of this flight fitted"
    )
    return replace(pb, held_out=segs, held_specs=specs, held_step_times=times, notes=list(pb.notes) + [note])
