"""The main job: scenario -> JSBSim flight -> log files -> ingest -> checks -> estimate ->
validate -> report.md / report.json / run.rrd (DESIGN.md section 5).

Estimation always starts from the written log files (the path a user's real log takes),
never from the simulator's in-memory tables. ``estimate_log`` is the same chain for a
real log with an aircraft description.
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from estimators import OutputError
from pipeline.errors import FsidError
from pipeline.identify import AircraftConstants, Problem, lateral_problem, longitudinal_problem
from pipeline.paths import atomic_write_text

#: methods the run knows; the scenario or the command line picks among them
METHODS = ("oem",)


class Progress:
    """Stage-by-stage progress on stderr: '[2/7] ingest flight.bin ... 1.2 s'."""

    def __init__(self, total: int, stream=None, quiet: bool = False) -> None:
        self.total, self.n, self.stream, self.quiet = total, 0, stream or sys.stderr, quiet
        self.t0 = time.perf_counter()

    def stage(self, text: str) -> "Progress":
        self.n += 1
        self._t = time.perf_counter()
        if not self.quiet:
            print(f"[{self.n}/{self.total}] {text} ...", end="", file=self.stream, flush=True)
        return self

    def done(self, extra: str = "") -> None:
        if not self.quiet:
            dt = time.perf_counter() - self._t
            print(f" {dt:.1f} s{(' - ' + extra) if extra else ''}", file=self.stream, flush=True)


def fit_problem(problem: Problem, method: str) -> Any:
    """Run one estimation method on a problem."""
    if method == "oem":
        return OutputError(problem.model, inputs=problem.inputs).fit(problem.fit, estimate_x0=problem.estimate_x0)
    raise FsidError(f"method {method!r} is not available in the run yet; use one of {METHODS}")


def identify(fd, ac: AircraftConstants, methods: Sequence[str], truth: Mapping[str, float] | None,
             progress: Progress, inputs: str = "linear") -> tuple[dict, dict, list[Problem]]:
    """Estimate and validate every axis the log excites; ``inputs`` is how the inputs vary
    between samples (estimators.integrators.INPUT_MODES). Returns (results, validations,
    problems); keys are the method names ("<axis>-<method>" once several axes are fitted)."""
    from pipeline.validate import validate

    results, validations, problems = {}, {}, []
    axes = {s.axis for s in fd.segments}
    builders = [("de" in axes, longitudinal_problem), (bool({"da", "dr"} & axes), lateral_problem)]
    skipped = []
    for wanted, build in builders:
        if not wanted:
            continue
        try:
            problem = build(fd, ac)
        except FsidError as exc:        # e.g. one maneuver only: say so, fit the other axis
            skipped.append(str(exc))
            continue
        problem.inputs = inputs
        problems.append(problem)
    if not problems:
        raise FsidError("no axis can be identified from this log: " + ("; ".join(skipped) or
                        "no control-input activity found (fly doublets/3-2-1-1s on the "
                        "elevator, aileron or rudder, or give segments)"))
    for msg in skipped:
        print(f"note: {msg}", file=progress.stream)
    for problem in problems:
        for m in methods:
            progress.stage(f"estimate {problem.axis} derivatives ({m.upper()}, "
                           f"{len(problem.fit)} maneuvers, {len(problem.held_out)} held out)")
            res = fit_problem(problem, m)
            progress.done(f"{'converged' if res.converged else 'NOT converged'} in "
                          f"{res.iterations} iterations")
            progress.stage(f"validate {problem.axis} {m.upper()} (fit, residuals, modes, proof of match)")
            key = m if len(problems) == 1 else f"{problem.axis}-{m}"
            results[key] = res
            validations[key] = validate(res, held_out=problem.held_out, truth=truth)
            progress.done()
    return results, validations, problems


def run_scenario(scenario_path: str | Path, out: Path, *, seed: int | None = None,
                 methods: Sequence[str] = ("oem",), quiet: bool = False) -> dict[str, Path]:
    """``fsid run``: everything of DESIGN.md section 5 into ``out``."""
    import sim
    from pipeline.checks import findings_to_json, run_checks, summarize
    from pipeline.readers import read_log
    from pipeline.writers import write_dataflash, write_mcap, write_truth_json

    pr = Progress(5 + 4 * len(methods) + 1, quiet=quiet)
    pr.stage(f"load scenario {scenario_path}")
    try:
        scenario = sim.load_scenario(scenario_path)
    except sim.ScenarioError as exc:
        raise FsidError(str(exc)) from None
    pr.done(scenario.name)
    pr.stage(f"fly {scenario.duration:.0f} s in JSBSim")
    result = sim.fly(scenario, seed=seed, workdir=out / ".jsbsim")
    pr.done(f"{len(result.maneuvers)} maneuvers")
    pr.stage("write flight.bin, flight.mcap, truth.json")
    write_dataflash(out / "flight.bin", result, airspeed="eas")   # ArduPilot semantics
    write_mcap(out / "flight.mcap", result)
    write_truth_json(out / "truth.json", result)
    truth_doc = json.loads((out / "truth.json").read_text())
    pr.done()
    pr.stage("ingest flight.bin and flight.mcap")
    fd_bin = read_log(out / "flight.bin")
    fd_mcap = read_log(out / "flight.mcap")
    pr.done(f"{len(fd_bin.channels)} channels, {len(fd_bin.segments)} maneuver segments")
    pr.stage("data-quality checks")
    findings = {"flight.bin": run_checks(fd_bin), "flight.mcap": run_checks(fd_mcap)}
    checks = {name: json.loads(findings_to_json(f, fd)) for (name, f), fd in
              zip(findings.items(), (fd_bin, fd_mcap))}
    atomic_write_text(out / "checks.json", json.dumps(checks, indent=2, default=str) + "\n")
    summary = {name: summarize(f) for name, f in findings.items()}
    pr.done(", ".join(f"{k}: {v}" for k, v in summary.items()))
    ac = AircraftConstants.from_truth(truth_doc)
    truth = {k: float(v) for k, v in truth_doc["derivatives"].items()}
    # estimation reads the product's own MCAP (surface positions at full resolution; the
    # .bin's RCOU carries whole-microsecond PWM, ~0.075 deg steps); the simulator moves
    # inputs linearly between samples, hence linear input interpolation
    results, validations, problems = identify(fd_mcap, ac, methods, truth, pr, inputs="linear")
    return _write_outputs(out, results, validations, problems, truth, pr, checks=summary,
                          meta={"scenario": scenario.name, "log": "flight.mcap", "seed": result.meta["seed"],
                                "aircraft": result.aircraft.name})


def estimate_log(log: str | Path, out: Path, *, aircraft: str | Path, map_path: str | None = None,
                 methods: Sequence[str] = ("oem",), inputs: str = "linear",
                 quiet: bool = False) -> dict[str, Path]:
    """``fsid estimate``: a real log and an aircraft TOML -> report and recording."""
    import sim
    from pipeline.checks import run_checks, summarize
    from pipeline.readers import read_log

    pr = Progress(3 + 4 * len(methods) + 1, quiet=quiet)
    pr.stage(f"read aircraft {aircraft}")
    try:
        ac_obj = sim.load_aircraft(aircraft)
    except sim.ScenarioError as exc:
        raise FsidError(str(exc)) from None
    ac = AircraftConstants.from_aircraft(ac_obj, getattr(ac_obj, "sensors", None))
    pr.done(ac_obj.name)
    pr.stage(f"ingest {log}")
    fd = read_log(log, map=map_path)
    pr.done(f"{len(fd.channels)} channels, {len(fd.segments)} segments")
    pr.stage("data-quality checks")
    summary = summarize(run_checks(fd))
    pr.done(str(summary))
    results, validations, problems = identify(fd, ac, methods, None, pr, inputs=inputs)
    return _write_outputs(out, results, validations, problems, None, pr, checks=summary,
                          meta={"log": str(log), "aircraft": ac_obj.name})


def _write_outputs(out: Path, results, validations, problems, truth, pr: Progress, *,
                   checks: Any, meta: Mapping[str, Any]) -> dict[str, Path]:
    from pipeline.recording import write_recording
    from pipeline.report import write_report

    pr.stage("write report.md, report.json, run.rrd")
    md, js = write_report(out, results, validations, truth=truth, meta=meta, checks=checks)
    rrd = write_recording(out / "run.rrd", results, validations, truth=truth)
    pr.done()
    return {"report.md": md, "report.json": js, "run.rrd": rrd}
