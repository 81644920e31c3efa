"""``run.rrd`` and ``check.rrd``: a run, or a checked log, for review in the rerun viewer
(rerun-sdk 0.41), written column-wise.

``check.rrd`` (``fsid check``) holds the whole flight (the ``/flight`` entities below);
``run.rrd`` (``fsid run`` / ``estimate`` / ``demo``) holds the fits and, when the job
passes the flight, the same ``/flight`` entities.

Every time history goes in with ONE ``send_columns`` call per entity (``rr.TimeColumn`` index
columns + ``rr.Scalars.columns``), never one call per sample. Each series entity also gets a
static ``rr.SeriesLines`` (legend name with unit, colour per method). The file is written to
a temporary name and renamed (:class:`pipeline.paths.atomic_path`).

Entity layout (stable; ``<out>``/``<in>`` are model output/input names, ``<method>`` the
keys of ``results`` such as ``oem``, ``<name>`` a parameter name with any character outside
``[A-Za-z0-9_.-]`` replaced by ``_``, so ``bias_az[0]`` becomes ``bias_az_0_``)::

    /README                               static TextDocument: this layout
    /summary/<method>                     static TextDocument: result.summary(truth)
    /outputs/<out>/measured               z            timelines t, segment
    /outputs/<out>/<method>               model y      t, segment
    /residuals/<method>/<out>             z - y        t, segment
    /inputs/<in>                          u            t, segment
    /match/<out>/measured                 held-out z   t, segment
    /match/<out>/<method>                 held-fixed model prediction of the held-out data
                                          (simulation, or air-data driven: report.json mode)
    /match/<out>/upper, /match/<out>/lower   measured +/- tolerance (judged channels only)
    /match/<out>/<method>/lower|upper     the prediction's range with the held-out segments'
                                          control steps between slow samples moved within
                                          their timing uncertainty (only when some has one)
    /match/<out>/<method>/model_lower|model_upper   the prediction -/+ 2 of its own std
                                          from the estimates' covariance
    /params/<name>/<method>               estimate per iteration (timeline ``iteration``) or,
                                          for filters, per sample (timelines t, segment)
    /params/<name>/<method>/upper|lower   estimate +/- std (final Cramer-Rao std for
                                          iterations; the step's std for filters)
    /params/<name>/truth                  true value on every iteration index of the
                                          longest history (and at the first and last t
                                          of a filter trajectory)
    /spectra/<method>/<out>               residual PSD, 10 log10(units^2/Hz) dB, timeline
                                          ``frequency`` = f in mHz (integer)
    /freq_response/<out>/<in>/mag_db/data            |H| of the spectral estimate (dB)
    /freq_response/<out>/<in>/mag_db/<method>        the model through the same estimator
    /freq_response/<out>/<in>/mag_db/<method>_linear G(jw) of the linearised model
    /freq_response/<out>/<in>/phase_deg/...          same three, phase in deg
    /freq_response/<out>/<in>/coherence              coherence of the data estimate [0, 1]
    /inverse/<method>/<in>                inverse simulation: residual input (needed - flown)
                                          on the first fitted segment, timelines t, segment
    /data/<channel>                       optional extra channels (``data=``), t, segment
    /flight/info                          static TextDocument: the log, what t = 0 is (its
                                          absolute start), channels, modes, windows, counts
    /flight/channels/<channel>            every canonical channel of the whole flight at its
                                          own samples, timeline t (channels above 200 Hz
                                          thinned for display: min and max per bin)
    /flight/mode                          StateChange track: the flight mode from each change
                                          ('no modes logged' at 0 when the log has none)
    /flight/maneuvers/<axis>              StateChange track per control axis (``time`` for
                                          windows given by time; ``<axis>_2`` ... for windows
                                          overlapping an earlier one): the window's name from
                                          its start, an empty state at its end
    /flight/plan/<axis>                   the maneuvers as designed, when known (a simulated
                                          flight's plan), tracks as the windows'
    /flight/segments/fitted, /held_out    (run.rrd) the fits' segments where they sit on t,
                                          by name (``_2`` ... tracks for overlapping ones)
    /flight/findings                      TextLog: each data-quality finding at its start
                                          (0 when it has none), level INFO/WARN/ERROR

Values are SI (rad, rad/s, m/s, m/s^2, N ...) as in the data contract, not degrees.
A time-series view plots against the time line selected in the time panel: ``t`` (the
default) for time histories, ``iteration`` for parameter convergence, ``frequency`` for
spectra and frequency responses. The blueprint sent with the file has one tab per group.

Timelines: ``t`` (duration, s, from the log's start: its first sample is 0); ``segment`` (sequence) the index of the segment a sample
belongs to; ``iteration`` (sequence) the optimiser iteration; ``frequency`` (sequence, mHz).
Segments are told apart by name (``Segment.name``, or ``#k`` by position when unnamed) and
their own times, so a maneuver fitted by several methods is one segment; they are numbered
in order of first appearance: the first result's fitted segments, its held-out ones, then
those of the next result not seen yet (another axis).
When all segments are disjoint in time (pieces of one log) they keep their own times on
``t`` (counted from the log's start when the flight is recorded, so they sit on the whole
flight's channels); when any overlap (e.g. each starts at 0) they are laid end to end in
that order, each starting 1 s (:data:`SEGMENT_GAP`) after the previous one ends, the
first at 0, or 1 s after the whole flight's end when it is recorded. A series' sample
count is the sum of its segments' finite samples; measured data (outputs, inputs, held-out
outputs) is written once per segment.

Filter methods (EKF/UKF) keep their parameter trajectory in ``result.extra["trajectory"]``
(per segment, DataFrames on t, one column per free parameter) and its std in
``result.extra["trajectory_std"]``; it is recorded on ``t``/``segment`` (same segment
layout as the outputs) instead of the iteration history.
"""

from __future__ import annotations

import uuid
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pandas as pd

from estimators import EstimationResult
from pipeline.errors import WRITE_REMEDY, FsidError
from pipeline.ingest.flightdata import SegmentSpec
from pipeline.outputs.recording_blueprint import build_blueprint, check_blueprint
from pipeline.outputs.recording_flight import FlightRecord, write_flight, write_tracks
from pipeline.outputs.recording_layout import SEGMENT_GAP, SegmentLayout, entity_part
from pipeline.outputs.recording_series import SeriesWriter, extra_data, parameter_histories, spectra, time_histories
from pipeline.paths import atomic_path


@contextmanager
def open_recording(path: Path, application_id: str, recording_id: str | None) -> Iterator[Any]:
    """A RecordingStream saving to a temporary file renamed onto ``path`` at the end."""
    import rerun as rr

    rec = rr.RecordingStream(application_id, recording_id=recording_id or str(uuid.uuid4()))
    try:
        with atomic_path(path) as tmp:
            rec.save(str(tmp))
            try:
                rec.send_recording_name(path.parent.name or path.stem)
                yield rec
            finally:
                rec.flush()
                rec.disconnect()
    except RuntimeError as exc:  # rerun's file writer stopped: a full disk or a size limit
        raise FsidError(f"cannot write {path}: the recording's file writer stopped ({exc}); {WRITE_REMEDY}") from None


def write_recording(
    path: str | Path,
    results: Mapping[str, EstimationResult],
    validations: Mapping[str, Mapping[str, Any]] | None = None,
    *,
    data: pd.DataFrame | Sequence[pd.DataFrame] | None = None,
    truth: Mapping[str, float] | None = None,
    inputs: Sequence[pd.DataFrame] | None = None,
    flight: FlightRecord | None = None,
    application_id: str = "fsid",
    recording_id: str | None = None,
    blueprint: bool = True,
) -> Path:
    """Write the rerun recording of a run (layout in the module doc); returns the path.

    results: method -> result (the first one's segments give the inputs and the time base);
    validations: method -> :func:`pipeline.validation.validate` output (its ``"arrays"`` give
    the spectra, frequency responses and proof-of-match histories; may be empty);
    data: optional extra channels, a DataFrame on t (s) or one per segment, SI units;
    truth: true parameter values; inputs: per fitted segment, DataFrames on t of the inputs
    (default: the first result's segments' u under the model's input names);
    flight: the whole flight the results were fitted on (its channels, modes, maneuver
    windows and findings under ``/flight``; the segments then sit on it).
    """
    if not results:
        raise ValueError("write_recording needs at least one result")
    validations = dict(validations or {})
    path = Path(path)
    with open_recording(path, application_id, recording_id) as rec:
        w = SeriesWriter(rec, list(results))
        w.text("/README", __doc__ or "")
        for m, r in results.items():
            w.text(f"/summary/{entity_part(m)}", "```\n" + r.summary(dict(truth) if truth else None) + "\n```")
        origin = flight.origin if flight is not None and flight.duration > 0 else 0.0
        start = flight.duration + SEGMENT_GAP if flight is not None and flight.duration > 0 else 0.0
        lay = SegmentLayout(results, validations, origin=origin, start=start)
        time_histories(w, results, validations, inputs, lay)
        parameter_histories(w, results, truth, lay)
        spectra(w, results, validations)
        if data is not None:
            extra_data(w, data)
        if flight is not None:
            write_flight(w, flight)
            spans = [SegmentSpec(n, a, b, "fit", axis="held_out" if h else "fitted") for n, a, b, h in lay.spans()]
            write_tracks(w, "/flight/segments", spans)
        if blueprint:
            rec.send_blueprint(build_blueprint(results, validations, flight))
    return path


def write_check_recording(
    path: str | Path,
    flight: FlightRecord,
    *,
    application_id: str = "fsid",
    recording_id: str | None = None,
    blueprint: bool = True,
) -> Path:
    """Write ``check.rrd``: the whole flight of ``fsid check`` (the ``/flight`` entities of
    the module doc, and ``/README``); returns the path."""
    path = Path(path)
    with open_recording(path, application_id, recording_id) as rec:
        w = SeriesWriter(rec, [])
        w.text("/README", __doc__ or "")
        write_flight(w, flight)
        if blueprint:
            rec.send_blueprint(check_blueprint(flight))
    return path
