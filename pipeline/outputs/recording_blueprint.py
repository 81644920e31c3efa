"""The blueprints sent with run.rrd and check.rrd: one tab per group of entities (outputs,
residuals, inputs, parameters, proof of match, spectra, frequency response, inverse
simulation, summary; the whole flight and its findings)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from estimators import EstimationResult
from pipeline.outputs.recording_flight import FlightRecord, flight_groups, plan_tracks, window_tracks
from pipeline.outputs.recording_layout import entity_part


def build_blueprint(
    results: Mapping[str, EstimationResult],
    validations: Mapping[str, Mapping[str, Any]],
    flight: FlightRecord | None = None,
) -> Any:
    """The rerun blueprint of a run's recording: its tabs, the whole flight's before the
    summary when ``flight`` is recorded (rerun.blueprint is imported here, rerun being
    optional)."""
    import rerun.blueprint as rrb

    ins = list(dict.fromkeys(i for r in results.values() for i in r.model.inputs))
    outs = list(dict.fromkeys(o for r in results.values() for o in r.outputs))
    params = list(dict.fromkeys(n for r in results.values() for n in r.free_names))
    tabs = [
        rrb.Grid(*[rrb.TimeSeriesView(origin=f"/outputs/{entity_part(o)}", name=o) for o in outs], name="outputs"),
        rrb.Grid(
            *[rrb.TimeSeriesView(origin=f"/residuals/{entity_part(m)}", name=f"residuals {m}") for m in results],
            name="residuals",
        ),
        rrb.Grid(*[rrb.TimeSeriesView(origin=f"/inputs/{entity_part(i)}", name=i) for i in ins], name="inputs"),
        rrb.Grid(*[rrb.TimeSeriesView(origin=f"/params/{entity_part(p)}", name=p) for p in params], name="parameters"),
    ]
    if any((v or {}).get("arrays", {}).get("match") for v in validations.values()):
        tabs.append(
            rrb.Grid(
                *[rrb.TimeSeriesView(origin=f"/match/{entity_part(o)}", name=o) for o in outs], name="proof of match"
            )
        )
    tabs.append(
        rrb.Grid(
            *[rrb.TimeSeriesView(origin=f"/spectra/{entity_part(m)}", name=f"PSD {m}") for m in results], name="spectra"
        )
    )
    pairs = list(
        dict.fromkeys(
            (o, i)
            for v in validations.values()
            for fr in [((v or {}).get("arrays") or {}).get("freq")]
            if fr
            for o in fr["outputs"]
            for i in fr["inputs"]
        )
    )
    if pairs:
        views = []
        for o, i in pairs:
            base = f"/freq_response/{entity_part(o)}/{entity_part(i)}"
            views.append(
                rrb.Vertical(
                    rrb.TimeSeriesView(origin=f"{base}/mag_db", name=f"{o}/{i} magnitude (dB)"),
                    rrb.TimeSeriesView(origin=f"{base}/phase_deg", name=f"{o}/{i} phase (deg)"),
                    rrb.TimeSeriesView(origin=f"{base}/coherence", name=f"{o}/{i} coherence"),
                    name=f"{o}/{i}",
                )
            )
        tabs.append(rrb.Grid(*views, name="frequency response"))
    if any(((v or {}).get("arrays") or {}).get("inverse") for v in validations.values()):
        tabs.append(
            rrb.Grid(
                *[
                    rrb.TimeSeriesView(origin=f"/inverse/{entity_part(m)}", name=f"inverse simulation {m}")
                    for m in results
                ],
                name="inverse simulation",
            )
        )
    if flight is not None:
        tabs += flight_tabs(flight)
    tabs.append(
        rrb.Vertical(
            rrb.TextDocumentView(origin="/README", name="layout"),
            *[rrb.TextDocumentView(origin=f"/summary/{entity_part(m)}", name=m) for m in results],
            name="summary",
        )
    )
    return rrb.Blueprint(rrb.Tabs(*tabs), rrb.TimePanel(timeline="t"), collapse_panels=False)


def flight_tabs(flight: FlightRecord) -> list[Any]:
    """The whole flight's tabs: the mode and maneuver tracks over the channels' panels
    (one per group, :data:`pipeline.outputs.recording_flight.CHANNEL_GROUPS`); the
    findings' log beside the flight's info."""
    import rerun.blueprint as rrb

    tracks = [
        "$origin/mode",
        *[f"$origin/maneuvers/{a}" for a in window_tracks(flight)],
        *[f"$origin/plan/{a}" for a in plan_tracks(flight)],
        "$origin/segments/**",
    ]
    panels = [
        rrb.TimeSeriesView(origin="/flight/channels", contents=[f"$origin/{entity_part(n)}" for n in names], name=group)
        for group, names in flight_groups(flight).items()
    ]
    return [
        rrb.Vertical(
            rrb.StateTimelineView(origin="/flight", contents=tracks, name="flight modes and maneuvers"),
            rrb.Grid(*panels, name="channels"),
            row_shares=[1, 4],
            name="flight",
        ),
        rrb.Horizontal(
            rrb.TextLogView(origin="/flight/findings", name="data-quality findings"),
            rrb.TextDocumentView(origin="/flight/info", name="the flight"),
            name="findings",
        ),
    ]


def check_blueprint(flight: FlightRecord) -> Any:
    """The blueprint of check.rrd: the flight, the findings, the layout."""
    import rerun.blueprint as rrb

    tabs = [*flight_tabs(flight), rrb.TextDocumentView(origin="/README", name="layout")]
    return rrb.Blueprint(rrb.Tabs(*tabs), rrb.TimePanel(timeline="t"), collapse_panels=False)
