"""``fsid simulate``: fly a scenario in JSBSim and write its logs - ``flight.mcap`` (the
product's own MCAP), ``flight.bin`` (ArduPilot DataFlash) and ``truth.json`` (truth set,
trim, sensor errors, seed, versions); a scenario with a ``[validation_flight]`` also
``validation.mcap`` and ``validation.bin``."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import sim
from pipeline.errors import FsidError
from pipeline.jobs.progress import Progress
from pipeline.outputs.writers import write_dataflash, write_mcap, write_truth_json
from pipeline.paths import new_run_dir

#: folder of the built-in scenarios (repository layout)
SCENARIO_DIR = Path(__file__).resolve().parents[2] / "scenarios"


def builtin_scenarios() -> list[str]:
    """Names of the built-in scenarios."""
    return sorted(p.stem for p in SCENARIO_DIR.glob("*.toml"))


def resolve_scenario(arg: str | Path) -> Path:
    """A scenario path from a path or a built-in name; FsidError when neither exists."""
    p = Path(arg)
    if p.is_file():
        return p
    cand = SCENARIO_DIR / f"{p.stem if p.suffix == '.toml' else arg}.toml"
    if p.parent == Path(".") and cand.is_file():
        return cand
    raise FsidError(
        f"scenario {arg!s} not found: give a scenario .toml path or a built-in name ({', '.join(builtin_scenarios())})"
    )


class _Progress:
    """Progress of the flight on stderr, in steps of 10 %, for flights long enough to need
    it."""

    def __init__(self, label: str, enabled: bool) -> None:
        self.label, self.enabled, self.last = label, enabled, -1

    def __call__(self, frac: float) -> None:
        pct = int(frac * 100)
        if self.enabled and pct // 10 != self.last // 10:
            self.last = pct
            end = "\r" if sys.stderr.isatty() else "\n"
            print(f"fsid simulate: {self.label}: flying {pct:3d} %", end=end, file=sys.stderr, flush=True)

    def done(self) -> None:
        if self.enabled and sys.stderr.isatty():
            print(file=sys.stderr)


def flight_stages(validation: bool) -> int:
    """The stages of :func:`simulate`: load, fly, write, and the validation flight's."""
    return 3 + int(validation)


def simulate(
    scenario_path: str | Path,
    out: str | Path | None = None,
    seed: int | None = None,
    keep_jsbsim: bool = False,
    progress: bool = True,
    *,
    airspeed: str = "tas",
    stages: bool = False,
    count: Progress | None = None,
    force: bool = True,
) -> tuple[Path, sim.SimResult]:
    """Fly ``scenario_path`` (a path or a built-in name) and write flight.mcap, flight.bin
    and truth.json into the run folder ``out`` (default: a new one under ./runs/), and
    validation.mcap, validation.bin when the scenario has a validation flight. Returns (run
    folder, SimResult). ScenarioError becomes FsidError. ``progress``: the flown fraction
    of a long flight on stderr; ``stages``: a progress line per stage instead (load, fly,
    write, the validation flight); ``airspeed``: the .bin's airspeed, "tas" or "eas"
    (ArduPilot's own semantics, :func:`pipeline.outputs.writers.write_dataflash`); ``count``:
    a job's Progress the stages continue (:func:`flight_stages` of them), instead of their own."""
    t0 = time.perf_counter()
    path = resolve_scenario(scenario_path)
    try:
        scenario = sim.load_scenario(path)
    except sim.ScenarioError as exc:
        raise FsidError(f"{exc} (fix the scenario file)") from None
    if seed is not None and seed < 0:
        raise FsidError(f"--seed {seed}: must be a non-negative integer")
    val = (scenario.with_seed(seed) if seed is not None else scenario).validation
    pr = count or Progress(flight_stages(val is not None), quiet=not stages)
    pr.stage(f"load scenario {scenario_path}", since=t0)
    pr.done(scenario.name)
    run_dir = new_run_dir("simulate", out, inputs=[path], logs=True, force=force)
    workdir = run_dir if keep_jsbsim else None
    prog = _Progress(scenario.name, progress and scenario.duration >= 120.0)
    pr.stage(f"fly {scenario.duration:.0f} s in JSBSim")
    try:
        result = sim.fly(scenario, seed=seed, workdir=workdir, progress=prog)
    except sim.ScenarioError as exc:
        raise FsidError(f"{exc} (fix the scenario's [trim] section)") from None
    prog.done()
    pr.done(f"{len(result.maneuvers)} maneuvers")
    if prog.enabled:
        print(f"fsid simulate: {scenario.name}: writing flight.mcap, flight.bin, truth.json", file=sys.stderr)
    pr.stage("write flight.mcap, flight.bin, truth.json")
    write_mcap(run_dir / "flight.mcap", result)
    write_dataflash(run_dir / "flight.bin", result, airspeed=airspeed)
    write_truth_json(run_dir / "truth.json", result)
    pr.done()
    if val is not None:
        calm = ", calm air" if val.turbulence.model == "off" else ""
        pr.stage(f"fly the validation flight ({val.duration:.0f} s{calm}), write validation.mcap, validation.bin")
        vres = sim.fly(val, workdir=workdir)
        write_mcap(run_dir / "validation.mcap", vres)
        write_dataflash(run_dir / "validation.bin", vres, airspeed=airspeed)
        pr.done(f"{len(vres.maneuvers)} maneuvers")
    return run_dir, result
