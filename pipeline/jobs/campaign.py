"""``fsid campaign``: Monte Carlo of a scenario, simulate + estimate over seeds and over varied
scenario keys, one Dask task per flight.

Each variant of the scenario (``--vary turbulence.severity=light,moderate``: every
combination of the values given; an array of tables such as ``maneuver`` takes the value in
every element that has the key) is written to DIR/variants/<label>.toml; each (variant, seed) is one task that
runs ``fsid run`` (:func:`pipeline.jobs.scenario.run_scenario`) in a scratch folder and
returns its rows: per method and parameter the estimate, its std and total std and the
truth. Seeds are explicit, so the rows do not depend on how many workers ran them. Per
variant, method and parameter the summary gives the bias (in empirical std), the empirical
std over the mean reported std (1 = honest bounds), the coverage of estimate +- 2 total std
and the failures: campaign.parquet (every row), campaign_summary.parquet, campaign.md/html.
"""

from __future__ import annotations

import copy
import itertools
import json
import math
import tempfile
import time
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from pipeline.errors import USER_ERRORS, FsidError, describe
from pipeline.jobs.dask_cluster import as_finished, dask_client
from pipeline.jobs.task_rows import report_rows, write_rows
from pipeline.paths import atomic_path, atomic_write_text, new_run_dir, release_run_dirs, run_id

COLUMNS = (
    "variant",
    "seed",
    "status",
    "reason",
    "method",
    "parameter",
    "estimate",
    "std",
    "total_std",
    "truth",
    "verdict",
    "seconds",
)


@dataclass(frozen=True)
class Flight:
    """One task: a scenario variant (its label, file and the values varied) and a seed."""

    variant: str
    scenario: str
    seed: int
    varied: tuple[tuple[str, Any], ...] = ()


@dataclass(frozen=True)
class CampaignOptions:
    """The campaign: ``scenario`` (TOML), ``seeds``, ``vary`` (dotted key -> values),
    ``methods`` (None: those that suit the flight plan), where the tasks run (``scheduler``
    or ``workers``), ``quiet``."""

    scenario: str | Path
    seeds: Sequence[int]
    vary: Mapping[str, Sequence[Any]] | None = None
    methods: Sequence[str] | None = None
    scheduler: str | None = None
    workers: int | None = None
    quiet: bool = False


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        if isinstance(v, float) and not math.isfinite(v):
            raise FsidError(f"a scenario value {v} is not finite")
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise FsidError(f"a scenario value of type {type(v).__name__} cannot be written")


def dump_toml(doc: Mapping[str, Any], prefix: str = "") -> str:
    """A TOML text of a scenario's parsed document (scalars, lists, tables, arrays of tables)."""
    plain = [(k, v) for k, v in doc.items() if not isinstance(v, dict) and not _tables(v)]
    lines = [f"{k} = {_toml_value(v)}" for k, v in plain]
    for k, v in doc.items():
        name = f"{prefix}{k}"
        if isinstance(v, dict):
            lines += ["", f"[{name}]", dump_toml(v, name + ".").strip()]
        elif _tables(v):
            for item in v:
                lines += ["", f"[[{name}]]", dump_toml(item, name + ".").strip()]
    return "\n".join(x for x in lines if x is not None) + "\n"


def _tables(v: Any) -> bool:
    return isinstance(v, list) and bool(v) and all(isinstance(x, dict) for x in v)


def _set(doc: dict, key: str, value: Any) -> None:
    """doc[key] for a dotted ``key``; through an array of tables, in every element that has
    the key (a maneuver's amplitude_deg: the surface maneuvers, not the throttle's)."""
    head, _, rest = key.partition(".")
    if not rest:
        doc[head] = value
        return
    node = doc.get(head)
    if node is None:
        node = doc[head] = {}
    items = node if isinstance(node, list) else [node]
    if not all(isinstance(n, dict) for n in items):
        raise FsidError(f"--vary {key}: {head} is not a table of the scenario")
    if isinstance(node, list):
        leaf = rest.split(".")[0]
        items = [n for n in items if leaf in n]
        if not items:
            raise FsidError(f"--vary {key}: no [[{head}]] of the scenario has {leaf}")
    for n in items:
        _set(n, rest, value)


def parse_value(text: str) -> Any:
    """A --vary value: a TOML number, boolean or string (bare words are strings)."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def variants(scenario: Path, vary: Mapping[str, Sequence[Any]] | None, folder: Path) -> list[tuple[str, Path, tuple]]:
    """(label, file, values) of every combination of the varied values (one, the scenario
    itself, without ``vary``), written under ``folder`` with the aircraft path made absolute."""
    import sim

    doc = tomllib.loads(scenario.read_text())
    ac = doc.get("aircraft")
    if isinstance(ac, str) and not Path(ac).is_absolute():
        doc["aircraft"] = str((scenario.parent / ac).resolve())
    keys = list(vary or {})
    out = []
    folder.mkdir(parents=True, exist_ok=True)
    for combo in itertools.product(*[list(vary[k]) for k in keys]) if keys else [()]:
        d = copy.deepcopy(doc)
        for k, v in zip(keys, combo):
            _set(d, k, v)
        label = ",".join(f"{k}={v}" for k, v in zip(keys, combo)) or scenario.stem
        path = folder / (_safe(label) + ".toml")
        atomic_write_text(path, dump_toml(d))
        try:
            sim.load_scenario(path)
        except sim.ScenarioError as exc:
            raise FsidError(f"--vary {label}: the scenario does not hold: {exc}") from None
        out.append((label, path, tuple(zip(keys, combo))))
    return out


def _safe(label: str) -> str:
    return "".join(c if c.isalnum() or c in "-_.=," else "_" for c in label)[:120]


def flight_task(flight: Flight, methods: Sequence[str] | None) -> list[dict[str, Any]]:
    """Simulate and estimate one (variant, seed) (in a worker); its rows."""
    from pipeline.jobs.scenario import run_scenario  # JSBSim, numerics: in the worker

    t0 = time.perf_counter()
    base = {"variant": flight.variant, "seed": flight.seed}
    try:
        with tempfile.TemporaryDirectory(prefix="fsid-campaign-") as tmp:
            run_scenario(flight.scenario, Path(tmp), seed=flight.seed, methods=methods, quiet=True, figures=False)
            rep = json.loads((Path(tmp) / "report.json").read_text())
            rows = [r for r in report_rows(rep) if r["truth"] is not None]
        status, reason = "ok", ""
    except Exception as exc:  # noqa: BLE001 - a flight's failure is that flight's record
        rows, status, reason = [], "refused" if isinstance(exc, USER_ERRORS) else "crashed", describe(exc)
    finally:
        release_run_dirs()
    seconds = time.perf_counter() - t0
    if not rows:
        return [{**base, "status": status, "reason": reason, "seconds": seconds}]
    return [{**base, **r, "status": status, "reason": reason, "seconds": seconds} for r in rows]


def summary(df: pd.DataFrame) -> pd.DataFrame:
    """Per variant, method and parameter: flights, bias (in empirical std), empirical /
    mean reported std, coverage of estimate +- 2 total std (module docstring)."""
    ok = df[(df["status"] == "ok") & df["estimate"].notna()]
    out = []
    for (v, m, p), g in ok.groupby(["variant", "method", "parameter"], sort=True):
        err = g["estimate"] - g["truth"]
        emp = float(g["estimate"].std(ddof=1)) if len(g) > 1 else float("nan")
        out.append(
            {
                "variant": v,
                "method": m,
                "parameter": p,
                "flights": len(g),
                "bias_in_std": float(err.mean()) / emp if emp > 0 else float("nan"),
                "empirical_over_reported": emp / float(g["std"].mean()) if g["std"].mean() > 0 else float("nan"),
                "coverage_2std": float((err.abs() <= 2 * g["total_std"]).mean()),
            }
        )
    fails = df[df["status"] != "ok"].groupby("variant").size()
    s = pd.DataFrame(out)
    if not s.empty:
        s["failed_flights"] = s["variant"].map(fails).fillna(0).astype(int)
    return s


def campaign(out: str | Path, opts: CampaignOptions) -> dict[str, Path]:
    """Run the campaign into ``out`` (module docstring); returns name -> path."""
    from pipeline.outputs.campaign import write_campaign_report  # matplotlib: at the end only

    out = new_run_dir("campaign", out, inputs=[opts.scenario])
    vs = variants(Path(opts.scenario), opts.vary, out / "variants")
    flights = [Flight(label, str(path), int(s), varied) for label, path, varied in vs for s in opts.seeds]
    say = (lambda s: None) if opts.quiet else (lambda s: print(s, flush=True))
    rows: list[dict[str, Any]] = []
    stopped, t0, n, failed = "", time.monotonic(), 0, 0
    try:
        with dask_client(opts.scheduler, opts.workers) as client:
            where = opts.scheduler or f"a local cluster of {len(client.scheduler_info()['workers'])} workers"
            say(f"{len(flights)} flights ({len(vs)} variants x {len(opts.seeds)} seeds) on {where}")
            for fl, got, exc in as_finished(
                client, flight_task, flights, opts.methods, key=lambda f: f"{_safe(f.variant)}-{f.seed}"
            ):
                if exc is not None:
                    got = [{"variant": fl.variant, "seed": fl.seed, "status": "crashed", "reason": describe(exc)}]
                rows += got
                n += 1
                failed += got[0]["status"] != "ok"
                _write(out / "campaign.parquet", rows)
                left = (time.monotonic() - t0) / n * (len(flights) - n)
                say(
                    f"[{n}/{len(flights)}{f', {failed} failed' if failed else ''}] {fl.variant} seed {fl.seed}: "
                    f"{got[0]['status']}  left {int(left // 60)}:{int(left % 60):02d}"
                )
    except KeyboardInterrupt:
        stopped = f"interrupted (Ctrl-C) after {n} of {len(flights)} flights"
    df = _write(out / "campaign.parquet", rows)
    s = summary(df)
    with atomic_path(out / "campaign_summary.parquet") as tmp:
        s.to_parquet(tmp, index=False)
    facts = {
        "run_id": run_id(out),
        "scenario": str(opts.scenario),
        "seeds": list(opts.seeds),
        "stopped": stopped,
        "variants": [label for label, _, _ in vs],
        "flights": len(flights),
    }
    paths = write_campaign_report(out, df, s, facts)
    if stopped:
        raise KeyboardInterrupt
    return {
        "campaign.parquet": out / "campaign.parquet",
        "campaign_summary.parquet": out / "campaign_summary.parquet",
        **{k: out / v for k, v in paths.items()},
    }


def _write(path: Path, rows: list[dict[str, Any]]) -> pd.DataFrame:
    """campaign.parquet of ``rows`` in a fixed order (variant, seed, method, parameter): the
    same whichever worker finished first."""
    return write_rows(path, rows, COLUMNS, ("variant", "seed", "method", "parameter"))
