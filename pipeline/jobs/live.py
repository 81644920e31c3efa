"""``fsid live``: identification while flying, from a MAVLink stream or a replayed log.

A stream (:class:`pipeline.ingest.stream.MavlinkReceiver`) is written to DIR/received.tlog
as it arrives; every ``tick`` the file is read again by the ingest (the same channels as any
log) and the rows that became final are added to the recursive frequency-domain equation
error of each axis (:class:`pipeline.methods.live_equations.LiveIdentification`). A replay
reads its log once and feeds the rows in flight time, at ``speed`` times real time (or as
fast as it can). Each second of flight the estimates go to the terminal and the recording
(DIR/live.rrd, a viewer with ``viewer``); a derivative whose std falls below the target is
said once ("Cmq: enough"). Ctrl-C, the end of a replay or ``idle`` seconds without a packet
stop it; the last rows are added and live.json, live.csv and the report are written.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pipeline.errors import FsidError
from pipeline.ingest.aircraft import aircraft_for_log, servo_travel_for
from pipeline.ingest.rawlog import LogReadError
from pipeline.ingest.readers import read_log
from pipeline.ingest.stream import MavlinkReceiver
from pipeline.methods.live_equations import (
    BAND_HZ,
    N_FREQUENCIES,
    TARGET_REL_STD,
    LiveIdentification,
    regression_constants,
)
from pipeline.outputs.live import LiveRecording, enough_events, status_lines, write_live
from pipeline.paths import new_run_dir, run_id, staged

#: the loop's period (s of wall time): how often the stream is read and the estimates updated
TICK_S = 0.25


@dataclass(frozen=True)
class LiveOptions:
    """``fsid live``'s settings: ``source`` (a MAVLink connection) or ``replay`` (a log);
    ``speed`` (times real time; None: as fast as possible) of a replay; ``aircraft`` (its
    mass, inertia, geometry, servo travel), ``map_path``; ``band`` (Hz), ``target`` (the
    relative std that is enough); ``idle`` (s without a packet that ends a stream; None:
    until Ctrl-C); ``viewer`` (spawn a rerun viewer); ``quiet``."""

    source: str | None = None
    replay: str | Path | None = None
    speed: float | None = 1.0
    aircraft: str | Path | None = None
    map_path: str | None = None
    band: tuple[float, float] = BAND_HZ
    target: float = TARGET_REL_STD
    idle: float | None = None
    viewer: bool = False
    quiet: bool = False


class _Display:
    """The terminal and the recording, once per second of flight."""

    def __init__(self, rec: LiveRecording, target: float, quiet: bool) -> None:
        self.rec, self.target, self.quiet = rec, target, quiet
        self.next_t = -float("inf")
        self.said: set[str] = set()
        self.history: list[tuple[float, Any]] = []

    def show(self, li: LiveIdentification, t: float, force: bool = False) -> None:
        if t < self.next_t and not (force and self.history and t > self.history[-1][0]):
            return
        self.next_t = t + 1.0
        est = li.estimates(t)
        if not est:
            return
        self.history.append((t, est))
        self.rec.log(t, est)
        if not self.quiet:
            for line in status_lines(t, est) + enough_events(est, self.said, self.target):
                print(line, flush=True)


def live(out: str | Path | None, opts: LiveOptions) -> dict[str, Path]:
    """Run ``fsid live`` into ``out`` (module docstring); returns name -> path."""
    if (opts.source is None) == (opts.replay is None):
        raise FsidError("fsid live needs a MAVLink SOURCE or --replay LOG (one of them)")
    out = new_run_dir("live", out, inputs=[opts.replay, opts.aircraft, opts.map_path])
    rec = LiveRecording(out / "live.rrd", spawn=opts.viewer, recording_id=run_id(out))
    disp = _Display(rec, opts.target, opts.quiet)
    wall0 = time.monotonic()
    try:
        if opts.replay is not None:
            li, t_end, stopped, facts = _replay(opts, disp)
        else:
            li, t_end, stopped, facts = _stream(out, opts, disp)
    finally:
        rec.close()
    final = li.estimates(t_end) if li is not None else {}
    doc = {
        "run_id": run_id(out),
        "source": str(opts.replay or opts.source),
        "stopped": stopped,
        "duration_s": t_end,
        "wall_s": time.monotonic() - wall0,
        "rows": sum(le.rows for le in li.live.values()) if li is not None else 0,
        "band_hz": list(opts.band),
        "n_frequencies": N_FREQUENCIES,
        "target": opts.target,
        "final": final,
        **facts,
    }
    with staged(out, "live.json") as stage:
        paths = write_live(stage, doc, disp.history)
    names = {**paths, "live.rrd": "live.rrd", **({"received.tlog": "received.tlog"} if opts.source else {})}
    return {n: out / rel for n, rel in names.items()}


def _aircraft(log: Path, opts: LiveOptions, fd: Any) -> LiveIdentification:
    ac, _, _ = aircraft_for_log(log, opts.aircraft, fd, required=True, say=(lambda s: None) if opts.quiet else print)
    return LiveIdentification(regression_constants(ac), opts.band, N_FREQUENCIES, opts.target)


def _replay(opts: LiveOptions, disp: _Display) -> tuple[LiveIdentification, float, str, dict]:
    """The log's rows fed in flight time at ``opts.speed`` x real time."""
    log = Path(opts.replay)
    fd = read_log(log, opts.map_path, servo_travel=servo_travel_for(log, opts.aircraft))
    li = _aircraft(log, opts, fd)
    t0, t_end = _span(fd)
    wall0 = time.monotonic()
    t = t0
    stopped = "end of the replay"
    try:
        while t < t_end:
            if opts.speed:
                time.sleep(TICK_S)
                t = min(t0 + (time.monotonic() - wall0) * opts.speed, t_end)
            else:
                t = min(t + 1.0, t_end)
            li.update(fd, until=t)
            disp.show(li, t)
    except KeyboardInterrupt:
        stopped = "Ctrl-C"
    li.update(fd, final=True, until=t)
    disp.show(li, t, force=True)
    return li, t - t0, stopped, {"speed": opts.speed or "max", "flight_s": t_end - t0}


def _span(fd: Any) -> tuple[float, float]:
    ts = [c.t for c in fd.channels.values() if len(c.t)]
    return min(float(t[0]) for t in ts), max(float(t[-1]) for t in ts)


def _stream(out: Path, opts: LiveOptions, disp: _Display) -> tuple[LiveIdentification | None, float, str, dict]:
    """Packets received into received.tlog; the file read again each tick."""
    path = out / "received.tlog"
    rx = MavlinkReceiver(opts.source, path)
    if not opts.quiet:
        print(f"receiving {opts.source} into {path} (Ctrl-C to stop)", flush=True)
    li, fd, t_now, stopped = None, None, 0.0, "Ctrl-C"
    travel = servo_travel_for(path, opts.aircraft)  # the aircraft file, read once
    latency = 0.0
    try:
        while True:
            got = rx.poll(TICK_S)
            if opts.idle is not None and rx.last_receive is not None and time.time() - rx.last_receive > opts.idle:
                stopped = f"no packet for {opts.idle:g} s"
                break
            if not got:
                continue
            received = rx.last_receive
            try:
                fd = read_log(path, opts.map_path, servo_travel=travel)
            except (FsidError, LogReadError):  # too little yet to read: wait for more
                continue
            if li is None:
                li = _aircraft(path, opts, fd)
            li.update(fd)
            t_now = _span(fd)[1]
            disp.show(li, t_now)
            latency = max(latency, time.time() - received)
    except KeyboardInterrupt:
        stopped = "Ctrl-C"
    finally:
        rx.close()
    if fd is not None and li is not None:
        try:
            fd = read_log(path, opts.map_path, servo_travel=travel)
        except (FsidError, LogReadError):
            pass
        li.update(fd, final=True)
        disp.show(li, t_now, force=True)
    facts = {"received": "received.tlog", "packets": rx.packets, "bad_packets": rx.bad, "update_latency_s": latency}
    return li, t_now, stopped, facts
