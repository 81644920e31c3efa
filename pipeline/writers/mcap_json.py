"""The product's own MCAP: one JSON-schema topic per sensor, plus controls and truth.

Topics (message encoding ``json``, schema encoding ``jsonschema``, one schema per topic):

* ``/sensors/<name>`` for every sensor of the flight (imu, airdata, attitude, baro,
  surfaces, gps): ``{"t": s, <channel>: value, ...}`` with canonical channel names in SI
  units (DESIGN.md section 3), at the sensor's own rate.
* ``/controls``: commanded deflections ``de_cmd, da_cmd, dr_cmd`` (rad), ``throttle`` (-)
  and ``thrust`` (N, = throttle * max thrust along body x), at ``truth_rate_hz``.
* ``/truth``: ``{"t": s, "truth": {column: value}}`` the noise-free truth table, every
  column of ``SimResult.truth``, at ``truth_rate_hz`` (default 50 Hz, a decimation of
  the simulation rate; ``None`` = every simulation step). Nested so that a
  canonical-name ingest never mistakes it for a sensor.

Every channel's metadata holds ``units`` (JSON object field -> unit), ``rate_hz`` and
``frame`` ("body FRD, NED"). ``log_time`` = ``publish_time`` = t in ns. Messages are
interleaved in time order. Nothing depends on the wall clock: identical inputs give
identical bytes.
"""
from __future__ import annotations

import json
import os

try:  # orjson formats floats several times faster than json (the writer's main cost)
    import orjson
except ImportError:  # pragma: no cover - same messages, slower
    orjson = None


def _dumps(obj) -> bytes:
    if orjson is not None:
        return orjson.dumps(obj)
    return json.dumps(obj, separators=(",", ":")).encode()

import numpy as np
import pandas as pd

from pipeline.paths import atomic_path

#: topic name -> (source, description)
TOPICS = {
    "/sensors/imu": "IMU at its mounting position: specific force (m/s^2) and body rates (rad/s)",
    "/sensors/airdata": "air-data boom: true airspeed V (m/s), vane alpha and beta (rad)",
    "/sensors/attitude": "attitude reference: phi, theta, psi (rad)",
    "/sensors/baro": "barometric altitude h (m, above sea level)",
    "/sensors/surfaces": "surface position sensors de, da, dr (rad) and throttle (-)",
    "/sensors/gps": "GPS velocity vn, ve, vd (m/s, NED) and altitude h (m)",
    "/controls": "commanded surface deflections (rad), throttle (-) and thrust (N)",
    "/truth": "noise-free simulation truth (SI units)",
}


def _schema(title: str, fields: list[str], units: dict[str, str], nested: str | None = None) -> bytes:
    props = {f: {"type": "number", "description": units.get(f, "")} for f in fields}
    if nested:
        body = {"t": {"type": "number", "description": "s"},
                nested: {"type": "object", "properties": props}}
        req = ["t", nested]
    else:
        body = props
        req = fields
    return json.dumps({"$schema": "https://json-schema.org/draft/2020-12/schema", "title": title,
                       "type": "object", "properties": body, "required": req}).encode()


def _lines(df: pd.DataFrame) -> list[bytes]:
    """One compact JSON object per row (floats in shortest round-trip form, NaN -> null)."""
    cols = [str(c) for c in df.columns]
    arr = np.ascontiguousarray(df.to_numpy(dtype=np.float64))
    if orjson is None or arr.size == 0:
        return [_dumps(dict(zip(cols, row))) for row in arr.tolist()]
    # one C-level dump of the whole table, then keys spliced in by bytes formatting
    body = orjson.dumps(arr, option=orjson.OPT_SERIALIZE_NUMPY)
    rows = body[2:-2].split(b"],[")
    tmpl = ("{" + ",".join(f"{json.dumps(c)}:%b" for c in cols) + "}").encode()
    return [tmpl % tuple(row.split(b",")) for row in rows]


def write_mcap(path: str | os.PathLike, result, truth_rate_hz: float | None = 50.0,
               compression: str = "lz4") -> None:
    """Write ``result`` (a :class:`sim.SimResult`) as an MCAP file at ``path`` (atomic).

    truth_rate_hz: rate of the /truth and /controls topics (Hz, rounded to a decimation
    of the simulation rate); None writes every simulation step.
    compression: chunk compression, "lz4" (default), "zstd" (smaller, slower) or "none"
    (about 1.7x larger files, a third faster to write).
    """
    from mcap.writer import CompressionType, Writer

    comp = {"lz4": CompressionType.LZ4, "zstd": CompressionType.ZSTD, "none": CompressionType.NONE}
    if compression not in comp:
        raise ValueError(f"compression must be one of {', '.join(comp)}, got {compression!r}")

    truth: pd.DataFrame = result.truth
    sim_rate = float(result.scenario.rate_hz)
    step = 1 if not truth_rate_hz else max(1, int(round(sim_rate / float(truth_rate_hz))))
    truth = truth.iloc[::step].reset_index(drop=True)
    out_rate = sim_rate / step
    units_truth = result.meta.get("truth_units", {})
    streams: list[tuple[str, str, dict[str, str], float, np.ndarray, list[bytes], str | None]] = []
    for name, df in result.sensors.items():
        spec = result.meta["sensors"][name]
        units = {"t": "s", **dict(zip(spec["channels"], spec["units"]))}
        streams.append((f"/sensors/{name}", f"fsid.sensors.{name}", units, spec["rate_hz"],
                        df["t"].to_numpy(), _lines(df), None))
    ctrl = pd.DataFrame({"t": truth["t"], "de_cmd": truth["de_cmd"], "da_cmd": truth["da_cmd"],
                         "dr_cmd": truth["dr_cmd"], "throttle": truth["throttle"], "thrust": truth["thrust"]})
    streams.append(("/controls", "fsid.controls", {"t": "s", "de_cmd": "rad", "da_cmd": "rad", "dr_cmd": "rad",
                                                    "throttle": "-", "thrust": "N"}, out_rate,
                    ctrl["t"].to_numpy(), _lines(ctrl), None))
    tr_lines = _lines(truth)
    tt = truth["t"].to_numpy()
    tr_msgs = [b'{"t":' + _dumps(float(t)) + b',"truth":' + ln + b"}" for t, ln in zip(tt, tr_lines)]
    streams.append(("/truth", "fsid.truth", {c: units_truth.get(c, "") for c in truth.columns},
                    out_rate, tt, tr_msgs, "truth"))

    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        w = Writer(fh, compression=comp[compression])
        w.start(profile="", library="fsid-sim")
        ids = []
        for topic, title, units, rate, _, _, nested in streams:
            fields = [c for c in units if c != "t"] if nested else list(units)
            sid = w.register_schema(name=title, encoding="jsonschema",
                                    data=_schema(title, fields, units, nested))
            meta = {"units": json.dumps(units), "rate_hz": repr(float(rate)), "frame": "body FRD, NED",
                    "description": TOPICS.get(topic, "")}
            ids.append(w.register_channel(topic=topic, message_encoding="json", schema_id=sid, metadata=meta))
        times = np.concatenate([s[4] for s in streams])
        which = np.concatenate([np.full(len(s[4]), i) for i, s in enumerate(streams)])
        index = np.concatenate([np.arange(len(s[4])) for s in streams])
        order = np.lexsort((which, times))
        ns = np.round(times * 1e9).astype(np.int64)
        seq = [0] * len(streams)
        for k in order:
            i = which[k]
            w.add_message(channel_id=ids[i], log_time=int(ns[k]), publish_time=int(ns[k]),
                          data=streams[i][5][index[k]], sequence=seq[i])
            seq[i] += 1
        w.add_metadata("fsid", {"scenario": result.scenario.name, "seed": str(result.meta["seed"]),
                                "aircraft": result.aircraft.name, "maneuvers": json.dumps(result.maneuvers)})
        w.finish()
