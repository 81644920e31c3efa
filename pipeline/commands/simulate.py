"""``fsid simulate SCENARIO [--out DIR] [--seed N]``: fly a scenario, write its logs.

Writes ``DIR/flight.mcap`` (the product's own MCAP), ``DIR/flight.bin`` (ArduPilot
DataFlash) and ``DIR/truth.json`` (truth set, trim, sensor errors, seed, versions); a
scenario with a ``[validation_flight]`` also ``DIR/validation.mcap`` and
``DIR/validation.bin`` (for ``fsid estimate DIR/flight.mcap --validate-with
DIR/validation.mcap``).
SCENARIO is a path to a scenario TOML or the name of a built-in one (``default``,
``longitudinal_3211_calm``, ... in the repository's ``scenarios/`` folder).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from pipeline.errors import FsidError
from pipeline.paths import new_run_dir

HELP = "fly a scenario in JSBSim (Dryden turbulence, sensor models) and write flight.mcap, flight.bin, truth.json"

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


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scenario", help="scenario .toml file or built-in name (e.g. default)")
    parser.add_argument("--out", metavar="DIR", help="output folder (default: a new folder under ./runs/)")
    parser.add_argument(
        "--seed", type=int, metavar="N", help="seed for turbulence and sensor noise (default: the scenario's seed)"
    )
    parser.add_argument(
        "--keep-jsbsim", action="store_true", help="keep the generated JSBSim aircraft XML in DIR/jsbsim"
    )


class _Progress:
    """Progress on stderr for runs that take long enough to need it."""

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


def simulate(
    scenario_path: str | Path,
    out: str | Path | None = None,
    seed: int | None = None,
    keep_jsbsim: bool = False,
    progress: bool = True,
):
    """Fly ``scenario_path`` and write flight.mcap, flight.bin and truth.json into the run
    folder (and validation.mcap, validation.bin when the scenario has a validation flight).
    Returns (run folder, SimResult). ScenarioError becomes FsidError."""
    import sim
    from pipeline.outputs.writers import write_dataflash, write_mcap, write_truth_json

    path = resolve_scenario(scenario_path)
    try:
        scenario = sim.load_scenario(path)
    except sim.ScenarioError as exc:
        raise FsidError(f"{exc} (fix the scenario file)") from None
    if seed is not None and seed < 0:
        raise FsidError(f"--seed {seed}: must be a non-negative integer")
    run_dir = new_run_dir("simulate", out)
    prog = _Progress(scenario.name, progress and scenario.duration >= 120.0)
    try:
        result = sim.fly(scenario, seed=seed, workdir=run_dir if keep_jsbsim else None, progress=prog)
    except sim.ScenarioError as exc:
        raise FsidError(f"{exc} (fix the scenario's [trim] section)") from None
    prog.done()
    if prog.enabled:
        print(f"fsid simulate: {scenario.name}: writing flight.mcap, flight.bin, truth.json", file=sys.stderr)
    write_mcap(run_dir / "flight.mcap", result)
    write_dataflash(run_dir / "flight.bin", result)
    write_truth_json(run_dir / "truth.json", result)
    val = (scenario.with_seed(seed) if seed is not None else scenario).validation
    if val is not None:
        vres = sim.fly(val, workdir=run_dir if keep_jsbsim else None)
        write_mcap(run_dir / "validation.mcap", vres)
        write_dataflash(run_dir / "validation.bin", vres)
    return run_dir, result


def run(args: argparse.Namespace) -> int:
    t0 = time.perf_counter()
    run_dir, result = simulate(args.scenario, args.out, args.seed, args.keep_jsbsim)
    dt = time.perf_counter() - t0
    s = result.scenario
    print(
        f"simulated {s.name} ({s.aircraft.name}, {s.duration:g} s, seed {result.meta['seed']}, "
        f"{len(result.maneuvers)} maneuvers) in {dt:.1f} s"
    )
    for f in ("flight.mcap", "flight.bin", "truth.json", "validation.mcap", "validation.bin"):
        if (run_dir / f).exists():
            print(f"wrote {run_dir / f}")
    return 0
