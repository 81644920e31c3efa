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

File layout: that of the ``mcap`` library's ``Writer`` (1.x) with its defaults (chunks
closed past 1 MiB, message indexes, repeated schemas and channels, statistics, summary
offsets, CRCs of chunks and summary), so a file is byte for byte what ``Writer`` writes
for the same messages. They do not go through ``Writer.add_message`` one at a time (a
Python call chain per message was most of the writer's time): the JSON of each table is
formatted at once and the message records, chunks and message indexes are assembled in
batches; the other records are encoded by ``mcap.records``.
"""

from __future__ import annotations

import json
import os
import struct
import zlib
from itertools import chain
from operator import itemgetter

try:  # orjson formats floats several times faster than json (the writer's main cost)
    import orjson
except ImportError:  # pragma: no cover - same messages, slower
    orjson = None

import numpy as np
import pandas as pd
from mcap.data_stream import RecordBuilder
from mcap.exceptions import UnsupportedCompressionError
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

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

#: bytes per chunk before it is closed (mcap.writer.Writer's default chunk_size)
CHUNK_SIZE = 1024 * 1024
_MAGIC = b"\x89MCAP0\r\n"
#: Message record up to its data: opcode, record length, channel id, sequence, log and
#: publish time (little-endian, packed: 31 bytes)
_MSG_HEAD = np.dtype([("op", "u1"), ("len", "<u8"), ("channel", "<u2"), ("seq", "<u4"), ("log", "<u8"), ("pub", "<u8")])
_OP_MESSAGE, _OP_MESSAGE_INDEX = 0x05, 0x07
_INDEX_ENTRY = np.dtype([("t", "<u8"), ("offset", "<u8")])


def _dumps(obj) -> bytes:
    if orjson is not None:
        return orjson.dumps(obj)
    return json.dumps(obj, separators=(",", ":")).encode()


def _schema(title: str, fields: list[str], units: dict[str, str], nested: str | None = None) -> bytes:
    props = {f: {"type": "number", "description": units.get(f, "")} for f in fields}
    if nested:
        body = {"t": {"type": "number", "description": "s"}, nested: {"type": "object", "properties": props}}
        req = ["t", nested]
    else:
        body = props
        req = fields
    return json.dumps(
        {
            "$schema": "https://json-schema.org/draft/2020-12/schema",
            "title": title,
            "type": "object",
            "properties": body,
            "required": req,
        }
    ).encode()


def _keys(cols) -> list[bytes]:
    """JSON text before each column's value in an object of these columns: '{"a":', ',"b":', ..."""
    return [(b"{" if j == 0 else b",") + json.dumps(str(c)).encode() + b":" for j, c in enumerate(cols)]


def _json_rows(arr: np.ndarray, keys: list[bytes], close: bytes = b"}") -> list[bytes]:
    """One JSON text per row of ``arr`` (N, len(keys)) float64: keys[j] then the value of
    column j, for every j, then ``close``. Floats in shortest round-trip form, NaN -> null.

    With orjson: one C-level dump of the whole table ("[v,v,...]", row-major), its commas
    turned into %b placeholders, and one bytes %-formatting that puts every key in place;
    no Python object per value (a number or null never holds a %)."""
    n, m = arr.shape
    if n == 0:
        return []
    if orjson is None or m == 0:
        return [b"".join(k + _dumps(v) for k, v in zip(keys, row)) + close for row in arr.tolist()]
    flat = orjson.dumps(np.ascontiguousarray(arr, dtype=np.float64).ravel(), option=orjson.OPT_SERIALIZE_NUMPY)
    template = b"%b" + flat[1:-1].replace(b",", b"%b") + close
    # the end of one row and the start of the next travel with the first key; JSON text
    # never holds a raw newline, so it marks the row boundaries
    first = [close + b"\n" + keys[0], *keys[1:]]
    return (template % tuple(keys + first * (n - 1))).split(b"\n")


def _lines(df: pd.DataFrame) -> list[bytes]:
    """One compact JSON object per row (floats in shortest round-trip form, NaN -> null)."""
    return _json_rows(df.to_numpy(dtype=np.float64), _keys(df.columns))


def _encode(*records) -> bytes:
    b = RecordBuilder()
    for r in records:
        r.write(b)
    return b.end()


def _compressor(compression: str):
    """(MCAP compression name, function bytes -> bytes) as mcap's Writer compresses chunks."""
    if compression == "none":
        return "", None
    if compression == "lz4":
        try:
            import lz4.frame
        except ImportError:
            raise UnsupportedCompressionError("lz4") from None
        return "lz4", lz4.frame.compress
    try:
        import zstandard
    except ImportError:
        raise UnsupportedCompressionError("zstandard") from None
    return "zstd", zstandard.compress


def _write_file(
    fh,
    channels: list[tuple[str, bytes, str, dict[str, str]]],
    chan: np.ndarray,
    log_ns: np.ndarray,
    seq: np.ndarray,
    data: list[bytes],
    compression: str,
    metadata: tuple[str, dict[str, str]],
    library: str,
) -> None:
    """Write an MCAP file as mcap.writer.Writer(fh, compression=...) does for: start(library),
    per channel i register_schema (title, "jsonschema", schema) then register_channel (topic,
    "json", metadata), add_message for every message in the given order, add_metadata,
    finish(). channels: (title, schema bytes, topic, channel metadata); chan (channel ids
    1..), log_ns (= publish time), seq, data: the messages in file order."""
    schemas = [
        Schema(id=i + 1, name=title, encoding="jsonschema", data=sch) for i, (title, sch, _, _) in enumerate(channels)
    ]
    chans = [
        Channel(id=i + 1, topic=topic, message_encoding="json", schema_id=i + 1, metadata=meta)
        for i, (_, _, topic, meta) in enumerate(channels)
    ]
    # a chunk opens with the schema and channel records when they were registered (the first)
    opening = _encode(*(r for pair in zip(schemas, chans) for r in pair))
    n = len(data)
    records, start, end = _message_records(chan, log_ns, seq, data)
    out = _Chunks([_MAGIC, _encode(Header(profile="", library=library))], records, start, chan, log_ns, compression)
    # chunks close once they exceed CHUNK_SIZE (after the message that crossed it); the last
    # open one closes at the end, after the metadata record
    a, base = 0, opening
    while a < n:
        done = int(start[a])
        b = int(np.searchsorted(end, CHUNK_SIZE - len(base) + done, side="right")) + 1
        if b > n:
            break
        out.close(a, b, base)
        a, base = b, b""
    meta_rec = _encode(Metadata(name=metadata[0], metadata=metadata[1]))
    meta_index = MetadataIndex(offset=out.pos, length=len(meta_rec), name=metadata[0])
    out.append(meta_rec)
    if a < n:
        out.close(a, n, base)
    out.append(_encode(DataEnd(data_section_crc=0)))
    counts: dict[int, int] = {}
    if n:
        ids, first, cnt = np.unique(chan, return_index=True, return_counts=True)
        counts = {int(ids[i]): int(cnt[i]) for i in np.argsort(first)}
    stats = Statistics(
        message_count=n,
        schema_count=len(schemas),
        channel_count=len(chans),
        attachment_count=0,
        metadata_count=1,
        chunk_count=len(out.indexes),
        message_start_time=int(log_ns.min()) if n else 0,
        message_end_time=max(0, int(log_ns.max())) if n else 0,
        channel_message_counts=counts,
    )
    groups = [
        (Opcode.SCHEMA, schemas),
        (Opcode.CHANNEL, chans),
        (Opcode.STATISTICS, [stats]),
        (Opcode.CHUNK_INDEX, out.indexes),
        (Opcode.ATTACHMENT_INDEX, []),
        (Opcode.METADATA_INDEX, [meta_index]),
    ]
    fh.write(b"".join(out.parts + _summary(groups, out.pos)))


def _message_records(
    chan: np.ndarray, log_ns: np.ndarray, seq: np.ndarray, data: list[bytes]
) -> tuple[list[bytes], np.ndarray, np.ndarray]:
    """The message records (header, data, header, data, ...) and each record's start and
    end offset among them [bytes]."""
    n = len(data)
    size = np.fromiter(map(len, data), dtype=np.int64, count=n) + _MSG_HEAD.itemsize
    head = np.empty(n, dtype=_MSG_HEAD)
    head["op"] = _OP_MESSAGE
    head["len"] = size - 9
    head["channel"] = chan
    head["seq"] = seq
    head["log"] = log_ns
    head["pub"] = log_ns
    records: list[bytes] = [b""] * (2 * n)
    records[0::2] = head.view(f"V{_MSG_HEAD.itemsize}").tolist()  # one bytes object per header
    records[1::2] = data
    end = np.cumsum(size)  # bytes of message records up to and including each
    start = end - size
    return records, start, end


class _Chunks:
    """The file's data section as it is written: its parts, their total length ``pos``,
    and the chunk indexes; :meth:`close` adds the chunk of messages a..b with their message
    indexes, as mcap's Writer closes a chunk."""

    def __init__(
        self,
        parts: list[bytes],
        records: list[bytes],
        start: np.ndarray,
        chan: np.ndarray,
        log_ns: np.ndarray,
        compression: str,
    ) -> None:
        self.parts = parts
        self.pos = sum(len(x) for x in parts)
        self.indexes: list = []
        self.records, self.start, self.chan, self.log_ns = records, start, chan, log_ns
        self.comp_name, self.compress = _compressor(compression)

    def append(self, rec: bytes) -> None:
        self.parts.append(rec)
        self.pos += len(rec)

    def close(self, a: int, b: int, base: bytes) -> None:
        """The chunk of messages a..b (after ``base``, the records that open it) and its
        message indexes, one per channel in order of first message."""
        body = base + b"".join(self.records[2 * a : 2 * b])
        packed = self.compress(body) if self.compress else body
        t = self.log_ns[a:b]
        chunk = _encode(
            Chunk(
                compression=self.comp_name,
                data=packed,
                message_start_time=int(t.min()),
                message_end_time=max(0, int(t.max())),
                uncompressed_crc=zlib.crc32(body),
                uncompressed_size=len(body),
            )
        )
        chunk_start = self.pos
        self.append(chunk)
        c = self.chan[a:b]
        at = len(base) + self.start[a:b] - self.start[a]  # offset of each message in the chunk
        ids, first = np.unique(c, return_index=True)
        offsets: dict[int, int] = {}
        index_len = 0
        for cid in ids[np.argsort(first)].tolist():  # channels in order of first message
            mask = c == cid
            entries = np.empty(int(mask.sum()), dtype=_INDEX_ENTRY)
            entries["t"], entries["offset"] = t[mask], at[mask]
            rec = struct.pack("<BQHI", _OP_MESSAGE_INDEX, 6 + entries.nbytes, cid, entries.nbytes) + entries.tobytes()
            offsets[cid] = self.pos + index_len
            self.parts.append(rec)
            index_len += len(rec)
        self.pos += index_len
        self.indexes.append(
            ChunkIndex(
                message_start_time=int(t.min()),
                message_end_time=max(0, int(t.max())),
                chunk_start_offset=chunk_start,
                chunk_length=len(chunk),
                message_index_offsets=offsets,
                message_index_length=index_len,
                compression=self.comp_name,
                compressed_size=len(packed),
                uncompressed_size=len(body),
            )
        )


def _summary(groups: list[tuple[int, list]], summary_start: int) -> list[bytes]:
    """The summary section (the record ``groups`` (opcode, records) from byte
    ``summary_start``), its summary offsets, the footer with the summary's CRC, the magic."""
    summary: list[bytes] = []
    offsets_rec = []
    at = summary_start
    for op, recs in groups:
        blob = _encode(*recs)
        offsets_rec.append(SummaryOffset(group_opcode=op, group_start=at, group_length=len(blob)))
        summary.append(blob)
        at += len(blob)
    summary_offset_start = at
    summary.append(_encode(*offsets_rec))
    summary_data = b"".join(summary)
    crc = zlib.crc32(
        struct.pack("<BQQQ", Opcode.FOOTER, 8 + 8 + 4, summary_start, summary_offset_start), zlib.crc32(summary_data)
    )
    return [
        summary_data,
        _encode(Footer(summary_start=summary_start, summary_offset_start=summary_offset_start, summary_crc=crc)),
        _MAGIC,
    ]


def write_mcap(path: str | os.PathLike, result, truth_rate_hz: float | None = 50.0, compression: str = "lz4") -> None:
    """Write ``result`` (a :class:`sim.SimResult`) as an MCAP file at ``path`` (atomic).

    truth_rate_hz: rate of the /truth and /controls topics (Hz, rounded to a decimation
    of the simulation rate); None writes every simulation step.
    compression: chunk compression, "lz4" (default), "zstd" (smaller, slower) or "none"
    (about twice as large, somewhat faster to write).
    """
    comp = ("lz4", "zstd", "none")
    if compression not in comp:
        raise ValueError(f"compression must be one of {', '.join(comp)}, got {compression!r}")

    truth: pd.DataFrame = result.truth
    sim_rate = float(result.scenario.rate_hz)
    step = 1 if not truth_rate_hz else max(1, int(round(sim_rate / float(truth_rate_hz))))
    truth = truth.iloc[::step].reset_index(drop=True)
    out_rate = sim_rate / step
    units_truth = result.meta.get("truth_units", {})
    # (topic, title, units, rate, t (s), one JSON message per row, nested)
    streams: list[tuple[str, str, dict[str, str], float, np.ndarray, list[bytes], str | None]] = []
    for name, df in result.sensors.items():
        spec = result.meta["sensors"][name]
        units = {"t": "s", **dict(zip(spec["channels"], spec["units"]))}
        streams.append(
            (f"/sensors/{name}", f"fsid.sensors.{name}", units, spec["rate_hz"], df["t"].to_numpy(), _lines(df), None)
        )
    ctrl = pd.DataFrame(
        {
            "t": truth["t"],
            "de_cmd": truth["de_cmd"],
            "da_cmd": truth["da_cmd"],
            "dr_cmd": truth["dr_cmd"],
            "throttle": truth["throttle"],
            "thrust": truth["thrust"],
        }
    )
    streams.append(
        (
            "/controls",
            "fsid.controls",
            {"t": "s", "de_cmd": "rad", "da_cmd": "rad", "dr_cmd": "rad", "throttle": "-", "thrust": "N"},
            out_rate,
            ctrl["t"].to_numpy(),
            _lines(ctrl),
            None,
        )
    )
    # {"t": t, "truth": {<every truth column, t first>}}: t written twice, as one table
    tt = truth["t"].to_numpy()
    keys = _keys(truth.columns)
    tr_msgs = _json_rows(
        np.column_stack([tt, truth.to_numpy(dtype=np.float64)]), [b'{"t":', b',"truth":' + keys[0], *keys[1:]], b"}}"
    )
    streams.append(
        ("/truth", "fsid.truth", {c: units_truth.get(c, "") for c in truth.columns}, out_rate, tt, tr_msgs, "truth")
    )

    channels = []
    for topic, title, units, rate, _, _, nested in streams:
        fields = [c for c in units if c != "t"] if nested else list(units)
        meta = {
            "units": json.dumps(units),
            "rate_hz": repr(float(rate)),
            "frame": "body FRD, NED",
            "description": TOPICS.get(topic, ""),
        }
        channels.append((title, _schema(title, fields, units, nested), topic, meta))
    # every message in time order (ties: in stream order), numbered per channel
    times = np.concatenate([s[4] for s in streams])
    which = np.concatenate([np.full(len(s[4]), i) for i, s in enumerate(streams)])
    order = np.lexsort((which, times))
    ns = np.round(times[order] * 1e9).astype(np.int64)
    chan = which[order] + 1
    seq = np.empty(len(order), dtype=np.int64)
    for i in range(len(streams)):
        mine = chan == i + 1
        seq[mine] = np.arange(np.count_nonzero(mine))
    payloads = list(chain.from_iterable(s[5] for s in streams))
    data = list(itemgetter(*order.tolist())(payloads)) if len(order) > 1 else [payloads[k] for k in order]
    info = {
        "scenario": result.scenario.name,
        "seed": str(result.meta["seed"]),
        "aircraft": result.aircraft.name,
        "maneuvers": json.dumps(result.maneuvers),
    }
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        _write_file(fh, channels, chan, ns, seq, data, compression, ("fsid", info), library="fsid-sim")
