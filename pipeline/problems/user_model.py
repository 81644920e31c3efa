"""User models for ``fsid estimate LOG --model path/to/file.py:name``.

``name`` in the Python file is an :class:`estimators.Model`, or a function returning one.
The function may take up to two positional arguments: the aircraft constants
(:class:`pipeline.ingest.constants.AircraftConstants`: mass, Ixx, Iyy, Izz, Ixz, S, b, cbar,
max_thrust, airdata and imu positions; ``None`` when no aircraft is known) and the
:class:`pipeline.ingest.flightdata.FlightData` of the log (e.g. for the trim airspeed of a
linear model). A first argument without a default needs ``--aircraft``.

The model's inputs and outputs are canonical channel names (DESIGN.md section 3) and are
read from the log as they are (absolute values, SI units): a perturbation model carries
its trim offsets itself (per-segment parameters or ``output_biases``). The segments are
the maneuvers found in the log on the model's inputs (all of the log's maneuvers when
none is on an input); with two or more, the last is held out for proof of match. Initial
states are estimated per segment, started from the log where a state is a channel.

Methods: everything that takes a model (oem, fem, ekf, ukf, soem, eigen, decouple); ``ls``
(equation error) needs the coefficient regressions of a built-in model. This module builds
the :class:`pipeline.problems.problem.Problem`; the jobs fit it as any other.
"""

from __future__ import annotations

import hashlib
import importlib.util
import inspect
import sys
from pathlib import Path
from typing import Any

import numpy as np

from estimators import Model, Segment
from pipeline.conditioning.input_sampling import step_times
from pipeline.conditioning.input_smoothing import smoothed_control_inputs
from pipeline.errors import FsidError
from pipeline.ingest.flightdata import CONTROL_INPUTS, FlightData, merge_overlapping
from pipeline.problems.problem import Problem
from pipeline.problems.windows import first_valid, multirate_frame, usable_segments, with_smoothed_inputs

#: --model values that select built-in models
BUILTIN_MODELS = ("auto", "longitudinal", "lateral")


def is_user_model(spec: str | None) -> bool:
    """True when ``--model`` names a file (``path.py:name``), not a built-in model."""
    return bool(spec) and spec not in BUILTIN_MODELS


def split_spec(spec: str) -> tuple[Path, str]:
    """``path/to/file.py:name`` -> (path, name); one clear error for anything else."""
    path, sep, name = spec.rpartition(":")
    if not sep or not path or not name.isidentifier():
        raise FsidError(
            f"--model {spec!r}: give a built-in model ({', '.join(BUILTIN_MODELS)}) "
            "or your own as path/to/file.py:name (name = an estimators.Model or a "
            "function returning one)"
        )
    return Path(path), name


def _import_file(path: Path) -> Any:
    if not path.is_file():
        raise FsidError(f"--model: model file {path} not found: check the path (give path/to/file.py:name)")
    key = "fsid_user_model_" + hashlib.sha1(str(path.resolve()).encode()).hexdigest()[:12]
    spec = importlib.util.spec_from_file_location(key, path)
    if spec is None or spec.loader is None:
        raise FsidError(f"--model: {path} cannot be imported as Python: give a .py file")
    module = importlib.util.module_from_spec(spec)
    sys.modules[key] = module  # dataclasses and numba look the module up by name
    here = str(path.resolve().parent)
    sys.path.insert(0, here)  # the model file may import its neighbours
    try:
        spec.loader.exec_module(module)
    except SystemExit as exc:  # the file ran as a script: it must not end fsid, and say nothing
        sys.modules.pop(key, None)
        raise FsidError(
            f"--model: importing {path} called sys.exit({exc.code!r}); a model file defines the model "
            "(put script code under if __name__ == '__main__':)"
        ) from None
    except Exception as exc:
        sys.modules.pop(key, None)
        where = ""
        if isinstance(exc, SyntaxError) and exc.lineno:
            where = f" (line {exc.lineno})"
        raise FsidError(
            f"--model: importing {path} failed{where}: {type(exc).__name__}: "
            f"{str(exc).splitlines()[0] if str(exc) else ''}; fix the model file"
        ) from None
    finally:
        try:
            sys.path.remove(here)
        except ValueError:
            pass
    return module


def _call(obj: Any, where: str, ac: Any, fd: FlightData | None) -> Any:
    try:
        params = [
            p
            for p in inspect.signature(obj).parameters.values()
            if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD, p.VAR_POSITIONAL)
        ]
    except (TypeError, ValueError):
        params = []
    n = 2 if any(p.kind == p.VAR_POSITIONAL for p in params) else min(len(params), 2)
    args: tuple = (ac, fd)[:n]
    if n and ac is None:
        if params[0].default is inspect.Parameter.empty and params[0].kind != params[0].VAR_POSITIONAL:
            raise FsidError(
                f"--model {where} takes the aircraft constants as its first argument "
                "but no aircraft is known: give --aircraft A.toml (or a default "
                "value for that argument)"
            )
        args = ()
    try:
        return obj(*args)
    except FsidError:
        raise
    except Exception as exc:
        raise FsidError(
            f"--model {where} failed when called: {type(exc).__name__}: "
            f"{str(exc).splitlines()[0] if str(exc) else ''}; fix the model file"
        ) from None


def load_user_model(spec: str, ac: Any = None, fd: FlightData | None = None) -> Model:
    """The :class:`estimators.Model` named by ``path.py:name`` (see the module docstring)."""
    path, name = split_spec(spec)
    module = _import_file(path)
    if not hasattr(module, name):
        found = sorted(
            k
            for k, v in vars(module).items()
            if not k.startswith("_")
            and (isinstance(v, Model) or (inspect.isfunction(v) and v.__module__ == module.__name__))
        )
        raise FsidError(
            f"--model: {path} defines no {name!r}; it defines "
            f"{', '.join(found) if found else 'no Model or function'}: "
            "give path/to/file.py:name with one of those"
        )
    obj = getattr(module, name)
    where = f"{path}:{name}"
    if not isinstance(obj, Model) and callable(obj) and not isinstance(obj, type):
        obj = _call(obj, where, ac, fd)
    if not isinstance(obj, Model):
        raise FsidError(
            f"--model {where} is a {type(obj).__name__}, not an estimators.Model "
            "(nor a function returning one): build it with "
            "estimators.Model(states=..., inputs=..., outputs=..., parameters=..., f=..., g=...)"
        )
    return obj


def check_channels(fd: FlightData, model: Model) -> None:
    """One error naming every model input/output the log does not have, and what it has."""
    miss_out = [c for c in model.outputs if c not in fd]
    miss_in = [c for c in model.inputs if c not in fd]
    if miss_out or miss_in:
        parts = ([f"output(s) {', '.join(miss_out)}"] if miss_out else []) + (
            [f"input(s) {', '.join(miss_in)}"] if miss_in else []
        )
        raise FsidError(
            f"model {model.name!r}: {' and '.join(parts)} not in the log "
            f"{fd.meta.get('source', '')}; the log has {', '.join(sorted(fd.names))}: "
            "use those names in the model (DESIGN.md section 3) or map the channels "
            "with --map"
        )


def user_model_problem(
    fd: FlightData, model: Model, *, rate_hz: float | None = None, hold_out: int = 1, smooth_inputs: bool = True
) -> Problem:
    """A :class:`pipeline.problems.problem.Problem` for a user model on the log's maneuvers
    (on a grid of ``rate_hz``, default the fastest channel's; the last ``hold_out`` of two or
    more held out for the proof of match); the model's inputs among the surface positions
    (de, da, dr) low-passed where their noise floor begins unless ``smooth_inputs`` is False
    (:mod:`pipeline.conditioning.input_smoothing`)."""
    check_channels(fd, model)
    on_inputs = [s for s in fd.segments if s.axis in model.inputs]
    specs = merge_overlapping(on_inputs or list(fd.segments))
    if not specs:
        raise FsidError(
            f"no maneuvers found in the log {fd.meta.get('source', '')} to fit the "
            f"model {model.name!r} to: fly doublets/3-2-1-1s on its inputs "
            f"({', '.join(model.inputs)})"
        )
    df, rate = multirate_frame(fd, list(model.outputs), list(model.inputs), rate_hz)
    # a user model may well be a hovering vehicle's: no airspeed rule
    specs, left_out, frames = usable_segments(
        df, specs, model.outputs, model.inputs, 0, f"{model.name!r} maneuver", airborne=False
    )
    hold = hold_out if len(specs) > hold_out else 0
    held = specs[len(specs) - hold :] if hold else []
    fit_specs = [s for s in specs if s not in held]
    controls = [c for c in model.inputs if c in CONTROL_INPUTS] if smooth_inputs else []
    smoothed, input_note = smoothed_control_inputs(fd, df, rate, controls)
    with_smoothed_inputs(frames, specs, smoothed, controls)

    def seg(s):
        w = frames[id(s)]
        x0 = np.array([first_valid(w, [x])[0] if x in w and w[x].notna().any() else 0.0 for x in model.states])
        return Segment(
            t=w["t"].to_numpy(),
            u=w[list(model.inputs)].to_numpy(),
            z=w[list(model.outputs)].to_numpy(),
            x0=x0,
            name=s.name,
        )

    notes = (
        [
            f"user model {model.name!r}: inputs {', '.join(model.inputs)}, outputs "
            f"{', '.join(model.outputs)} from the log's channels",
            f"grid {rate:g} Hz; slower channels at their own samples only",
            f"segments: {'maneuvers on ' + '/'.join(sorted({s.axis for s in specs})) if on_inputs else 'all maneuvers of the log'}"
            f"; {'held out for proof of match: ' + held[0].name if held else 'none held out' + (' (one maneuver only)' if hold_out else '')}",
        ]
        + ([input_note] if input_note else [])
        + left_out
    )
    return Problem(
        model.name,
        model,
        [seg(s) for s in fit_specs],
        [seg(s) for s in held],
        fit_specs,
        held,
        estimate_x0=True,
        notes=notes,
        rate_hz=rate,
        step_times=step_times(fd.meta),
    )
