"""``fsid run``: ``fsid simulate`` (scenario -> JSBSim flight -> log files and truth.json),
then the estimate job on the written log (DESIGN.md section 5), the truth attached for the
report only.

Estimation starts from the written log files (the path a user's real log takes), never from
the simulator's in-memory tables: the product's own MCAP (surface positions at full
resolution; the .bin's RCOU carries whole-microsecond PWM), with the inputs linear between
samples as the simulator moves them. The flight plan chooses the methods that suit it and
says whether the flights were flown in calm air; no truth value (noise levels, the
turbulence level, derivatives, sensor errors) enters an estimate.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import sim
from pipeline.conditioning.checks import findings_to_json, run_checks, summarize
from pipeline.conditioning.input_sampling import time_steps
from pipeline.errors import FsidError
from pipeline.ingest.readers import read_log
from pipeline.jobs.estimate import Estimated, estimate, stage_count
from pipeline.jobs.identify import planned_axes
from pipeline.jobs.options import EstimateOptions, RunOptions
from pipeline.jobs.progress import Progress
from pipeline.jobs.simulate import flight_stages, resolve_scenario, simulate
from pipeline.jobs.write import write_outputs
from pipeline.outputs.recording_flight import FlightRecord, planned_maneuvers
from pipeline.paths import run_id
from pipeline.problems import MAX_RATE_HZ
from pipeline.registry import check_methods, scenario_methods


def run_scenario(
    scenario_path: str | Path, out: Path, options: RunOptions | None = None, **settings: Any
) -> dict[str, Path]:
    """``fsid run``: everything of DESIGN.md section 5 into ``out``; returns name -> path of
    the report and the recording. ``options`` (default RunOptions()), or its fields as
    keywords (``settings`` replace those of ``options``): ``methods`` default: the ones that
    suit the flight plan (:func:`pipeline.registry.scenario_methods`). ``compat``:
    run the sensor-compatibility stage and estimate from its corrected data (its document
    goes to checks.json under ``flight.mcap.compatibility`` and to the report). ``bands``:
    proof-of-match bands over the scenario's ``[validation]``. The scenario's validation
    flight, when it has one, is the proof of match.

    One progress count, planned from the flight plan: the flight's stages
    (:func:`pipeline.jobs.simulate.simulate`), then the estimate job's
    (:func:`pipeline.jobs.estimate.estimate`)."""
    opts = replace(options or RunOptions(), **settings)
    if opts.methods:
        check_methods(opts.methods)
    count = _planned_count(scenario_path, opts)
    _, result = simulate(scenario_path, out, progress=False, seed=opts.seed, airspeed="eas", count=count)
    scenario, val = result.scenario, result.scenario.validation
    truth_doc = json.loads((out / "truth.json").read_text())
    est = estimate(
        out / "flight.mcap",
        EstimateOptions(
            **{**opts.shared(), "bands": {**scenario.pom_bands, **(opts.bands or {})}},
            methods=list(opts.methods or scenario_methods(truth_doc)),
            validation_log=None if val is None else out / "validation.mcap",
            calm=scenario.turbulence.model == "off",
            validation_calm=val is not None and val.turbulence.model == "off",
        ),
        count=count,
    )
    checks, checks_json = _checks(out, est, val is not None)
    meta = {
        "scenario": scenario.name,
        "log": "flight.mcap",
        "seed": result.meta["seed"],
        "aircraft": result.aircraft.name,
        **{k: v for k, v in est.meta.items() if k not in ("log", "aircraft", "validation flight", "truth")},
    }
    corrections = meta.pop("validation flight corrections", None)
    if val is not None:
        meta["validation flight"] = (
            f"validation.mcap (seed {val.seed}, "
            f"{'calm air' if val.turbulence.model == 'off' else 'turbulence as the flight'}): "
            "the proof of match; every maneuver of flight.mcap fitted"
        )
    if corrections is not None:
        meta["validation flight corrections"] = corrections
    return write_outputs(
        out,
        est.results,
        est.validations,
        est.truth,
        est.progress,
        checks=checks,
        meta=meta,
        compatibility=est.comp,
        flight=FlightRecord(est.data, est.findings, plan=planned_maneuvers(result.maneuvers)),
        figures=opts.figures,
        files={"checks.json": checks_json},
    )


def _planned_count(scenario_path: str | Path, opts: RunOptions) -> Progress:
    """The run's one progress count, from its flight plan before anything is flown: the
    flight's stages and the estimate job's, with the methods that suit the plan and the
    axes its maneuvers move."""
    try:
        scenario = sim.load_scenario(resolve_scenario(scenario_path))
    except sim.ScenarioError as exc:
        raise FsidError(f"{exc} (fix the scenario file)") from None
    plan = {"sas": bool(scenario.sas_k_alpha or scenario.sas_k_q), "turbulence": {"model": scenario.turbulence.model}}
    methods = opts.methods or scenario_methods(plan)
    val = scenario.validation is not None
    n_axes = planned_axes({a for m in scenario.maneuvers for a in m.axes})
    stages = flight_stages(val) + stage_count(len(methods), n_axes, int(val), user=False)
    return Progress(stages, quiet=opts.quiet)


def _checks(out: Path, est: Estimated, validation: bool) -> tuple[dict[str, dict[str, int]], str]:
    """checks.json: the data-quality findings of flight.bin, flight.mcap (with the
    compatibility document) and validation.mcap, each stamped with the run's id; returns
    their summaries by file and the document's text."""
    fd_bin = read_log(out / "flight.bin")
    logs = {"flight.bin": (run_checks(fd_bin), fd_bin), "flight.mcap": (est.findings, est.data)}
    if validation:
        fd_val = time_steps(read_log(out / "validation.mcap"), MAX_RATE_HZ)[0]
        logs["validation.mcap"] = (run_checks(fd_val), fd_val)
    checks = {name: json.loads(findings_to_json(f, fd)) for name, (f, fd) in logs.items()}
    checks["flight.mcap"]["compatibility"] = est.comp
    for doc in checks.values():
        doc["run_id"] = run_id(out)
    return {name: summarize(f) for name, (f, _) in logs.items()}, json.dumps(checks, indent=2, default=str) + "\n"
