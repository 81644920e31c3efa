"""MCAP reader: JSON, ROS 2 (CDR, mcap-ros2-support) and protobuf (mcap-protobuf-support).

Records are streamed (``mcap.stream_reader.StreamReader``), decoded one at a time and
flattened into per-topic numeric columns (``angular_velocity.x``, ``data[0]``); no
decoded message objects are kept. One table per topic, named by the topic; its schema
name is in ``Table.units['__schema__']`` so maps can select by schema (``@sensor_msgs/msg/Imu``).

Time base (``time_base``): "header" uses ``header.stamp`` (ROS) or a top-level ``t`` /
``timestamp`` field [s] when every message of the topic has one; "log" uses the MCAP
``log_time``; "auto" (default) prefers header stamps per topic. The choice per topic is
in ``RawLog.info['time_base_by_topic']``.

Poses: a ROS 2 pose message (``geometry_msgs/msg/PoseStamped``, ``PoseWithCovarianceStamped``,
``nav_msgs/msg/Odometry``) follows REP 103, world ENU and body FLU; its table also gets the
pose in the canonical frames, world NED and body FRD (DESIGN.md section 3), as columns
``ned.x_n ned.y_e ned.z_d ned.q_w ned.q_x ned.q_y ned.q_z`` (:func:`ros_pose_ned`): a
quaternion's change of frames mixes its components, which a channel map's per-field sign
cannot express.

Damage: reading stops at the first record that cannot be read; everything before it is
kept and ``RawLog.damage`` holds the byte offset.
"""

from __future__ import annotations

import json
import math
import os
from array import array
from collections import defaultdict
from pathlib import Path

import numpy as np
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader
from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoderFactory
from mcap_ros2.decoder import DecoderFactory as Ros2DecoderFactory

from pipeline.ingest.rawlog import TIME_BASES, Damage, LogReadError, RawLog, Table

_HEADER_TIME_FIELDS = ("header.stamp", "t", "timestamp")
#: ROS 2 pose schemas -> the prefix of their geometry_msgs/Pose fields
ROS_POSES = {
    "geometry_msgs/msg/PoseStamped": "pose",
    "geometry_msgs/msg/PoseWithCovarianceStamped": "pose.pose",
    "nav_msgs/msg/Odometry": "pose.pose",
}


def ros_pose_ned(cols: dict[str, np.ndarray], prefix: str) -> dict[str, np.ndarray]:
    """The pose in columns ``{prefix}.position.x`` ... ``{prefix}.orientation.w`` (REP 103:
    world ENU, body FLU) as canonical columns ``ned.x_n`` ... ``ned.q_z`` (world NED, body
    FRD, quaternion body -> NED, w first); {} when a field is missing.

    Position: x_n = y, y_e = x, z_d = -z. Attitude: q_NED/FRD = a (x) q_ENU/FLU (x) b with
    a = (0, 1, 1, 0)/sqrt 2 (ENU -> NED, half a turn about north-east) and b = (0, 1, 0, 0)
    (FRD -> FLU, half a turn about x): (w + z, x + y, x - y, w - z)/sqrt 2."""
    names = [f"{prefix}.position.{a}" for a in "xyz"] + [f"{prefix}.orientation.{a}" for a in "wxyz"]
    if any(n not in cols for n in names):
        return {}
    x, y, z, qw, qx, qy, qz = (np.asarray(cols[n], dtype=float) for n in names)
    s = 1.0 / np.sqrt(2.0)
    return {
        "ned.x_n": y,
        "ned.y_e": x,
        "ned.z_d": -z,
        "ned.q_w": s * (qw + qz),
        "ned.q_x": s * (qx + qy),
        "ned.q_y": s * (qx - qy),
        "ned.q_z": s * (qw - qz),
    }


class _Counting:
    """File wrapper remembering how far the stream reader has read (for damage offsets)."""

    def __init__(self, fh):
        self.fh = fh

    def read(self, n=-1):
        return self.fh.read(n)

    def tell(self):
        return self.fh.tell()

    def readable(self):
        return True


def _flatten(obj, prefix: str, out: dict) -> None:
    if obj is None:
        return
    if isinstance(obj, bool):
        out[prefix] = float(obj)
    elif isinstance(obj, (int, float)):
        out[prefix] = float(obj)
    elif isinstance(obj, dict):
        for k, v in obj.items():
            _flatten(v, f"{prefix}.{k}" if prefix else str(k), out)
    elif isinstance(obj, (list, tuple)):
        if len(obj) <= 64:
            for i, v in enumerate(obj):
                _flatten(v, f"{prefix}[{i}]", out)
    elif isinstance(obj, (bytes, bytearray, str)):
        return
    elif hasattr(obj, "DESCRIPTOR") and hasattr(obj, "ListFields"):  # protobuf
        for fd in obj.DESCRIPTOR.fields:  # all fields: proto3 omits zeros from ListFields
            v = getattr(obj, fd.name)
            rep = getattr(fd, "is_repeated", None)
            if rep is None:
                rep = getattr(fd, "label", 1) == 3
            if rep:
                v = list(v)
            _flatten(v, f"{prefix}.{fd.name}" if prefix else fd.name, out)
    elif hasattr(obj, "__slots__") or hasattr(obj, "__dict__"):  # ROS 2 dynamic messages
        names = getattr(obj, "__slots__", None) or list(vars(obj))
        for k in names:
            if k.startswith("_"):
                continue
            _flatten(getattr(obj, k, None), f"{prefix}.{k}" if prefix else k, out)
    elif hasattr(obj, "tolist"):
        _flatten(obj.tolist(), prefix, out)


def _stamp(flat: dict) -> float | None:
    if "header.stamp.sec" in flat:
        return flat["header.stamp.sec"] + flat.get("header.stamp.nanosec", flat.get("header.stamp.nsec", 0.0)) * 1e-9
    if "header.stamp.seconds" in flat:  # foxglove-style protobuf
        return flat["header.stamp.seconds"] + flat.get("header.stamp.nanos", 0.0) * 1e-9
    if "timestamp.seconds" in flat:
        return flat["timestamp.seconds"] + flat.get("timestamp.nanos", 0.0) * 1e-9
    if "t" in flat:
        return flat["t"]
    return None


class _Topics:
    """Decoded messages per topic as compact per-field buffers (8 bytes a value), never
    the decoded messages; their log and header times, schema and encoding."""

    def __init__(self) -> None:
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.decoders: dict[int, object] = {}
        self.cols: dict[str, dict[str, array]] = defaultdict(lambda: defaultdict(lambda: array("d")))
        self.log_t: dict[str, list] = defaultdict(list)
        self.hdr_t: dict[str, list] = defaultdict(list)
        self.counts: dict[str, int] = defaultdict(int)
        self.schema_of: dict[str, str] = {}
        self.encoding_of: dict[str, str] = {}
        self.undecodable: dict[str, str] = {}
        self.n_msgs = 0

    def add(self, rec) -> bool:
        """Take one record: a schema or channel is kept, a message decoded and flattened;
        False for a message skipped (no channel or no decoder for it)."""
        if isinstance(rec, Schema):
            self.schemas[rec.id] = rec
        elif isinstance(rec, Channel):
            self.channels[rec.id] = rec
        elif isinstance(rec, Message):
            return self._message(rec)
        return True

    def _message(self, rec) -> bool:
        ch = self.channels.get(rec.channel_id)
        if ch is None:
            return False
        topic = ch.topic
        dec = self.decoders.get(ch.id)
        if dec is None and ch.id not in self.decoders:
            dec = self.decoders[ch.id] = _decoder_for(ch, self.schemas.get(ch.schema_id))
            sc = self.schemas.get(ch.schema_id)
            self.schema_of[topic] = sc.name if sc else ""
            self.encoding_of[topic] = ch.message_encoding
            if dec is None:
                self.undecodable[topic] = f"no decoder for message encoding '{ch.message_encoding}'"
        if dec is None:
            return False
        try:
            obj = dec(rec.data)
        except Exception as exc:
            raise _BadMessage(f"topic {topic}: message cannot be decoded ({exc})") from None
        flat: dict[str, float] = {}
        _flatten(obj, "", flat)
        k = self.counts[topic]
        tc = self.cols[topic]
        for f, v in flat.items():
            lst = tc[f]
            if len(lst) < k:  # field absent in earlier messages
                lst.extend([math.nan] * (k - len(lst)))
            if len(lst) > k:  # duplicate key after flattening: keep the first
                continue
            lst.append(v)
        self.counts[topic] = k + 1
        self.log_t[topic].append(rec.log_time * 1e-9)
        st = _stamp(flat)
        self.hdr_t[topic].append(math.nan if st is None else st)
        self.n_msgs += 1
        return True

    def tables(self, time_base: str) -> tuple[dict[str, Table], dict[str, str]]:
        """One table per topic on its chosen time base, and that choice per topic."""
        tables: dict[str, Table] = {}
        tb_by_topic: dict[str, str] = {}
        for topic, tc in self.cols.items():
            n = self.counts[topic]
            arrs = {}
            for f, lst in tc.items():
                if len(lst) < n:
                    lst.extend([math.nan] * (n - len(lst)))
                arrs[f] = np.frombuffer(lst, dtype=np.float64).copy()
            prefix = ROS_POSES.get(self.schema_of.get(topic, ""))
            if prefix and self.encoding_of.get(topic) == "cdr":
                arrs.update(ros_pose_ned(arrs, prefix))
            lt = np.asarray(self.log_t[topic])
            ht = np.asarray(self.hdr_t[topic])
            use_hdr = time_base in ("auto", "header") and n > 0 and np.all(np.isfinite(ht)) and np.any(ht != 0)
            if time_base == "header" and not use_hdr:
                tb_by_topic[topic] = "log_time (no header stamps)"
            else:
                tb_by_topic[topic] = "header stamp" if use_hdr else "log_time"
            tables[topic] = Table(
                topic,
                ht if use_hdr else lt,
                arrs,
                {"__schema__": self.schema_of.get(topic, ""), "__encoding__": self.encoding_of.get(topic, "")},
            )
        for topic in self.undecodable:
            tables.setdefault(topic, Table(topic, np.zeros(0), {}, {"__schema__": self.schema_of.get(topic, "")}))
        return tables, tb_by_topic


def _stream(fh, topics: _Topics) -> Damage | None:
    """Every record of the open file into ``topics``; the damage where reading stopped (the
    offset after the last record taken)."""
    last_good = 0
    try:
        reader = StreamReader(fh, skip_magic=False, record_size_limit=1 << 30)
        for rec in reader.records:
            if not topics.add(rec):
                continue
            try:
                last_good = fh.tell()
            except (OSError, ValueError):
                pass
    except Exception as exc:  # mcap raises many kinds on damaged input
        at = last_good
        msg = str(exc) or type(exc).__name__
        return Damage(at, f"byte {at}", f"MCAP unreadable after byte {at}: {msg}", topics.n_msgs, 0)
    return None


def read_mcap(path: str | os.PathLike, *, strict: bool = False, time_base: str = "auto") -> RawLog:
    """Read an MCAP file into one table per topic (see module docstring)."""
    if time_base not in TIME_BASES["mcap"]:
        raise LogReadError(
            f"time_base must be auto, header or log (got {time_base!r})", path=str(path), where="options"
        )
    path = Path(path)
    try:
        fh = open(path, "rb")
    except OSError as exc:
        raise LogReadError.cannot_open(path, exc) from None
    topics = _Topics()
    try:
        damage = _stream(fh, topics)
    finally:
        fh.close()
    if topics.n_msgs == 0 and damage is not None and not topics.channels:
        raise LogReadError(
            f"{path}: not a readable MCAP file ({damage.message})",
            path=str(path),
            offset=damage.offset,
            where=damage.where,
        )
    if strict and damage is not None:
        raise LogReadError(f"{path}: {damage.message}", path=str(path), offset=damage.offset, where=damage.where)
    tables, tb_by_topic = topics.tables(time_base)
    kinds = set(tb_by_topic.values())
    desc = (
        "header stamps (message header.stamp / t field), in s"
        if kinds == {"header stamp"}
        else "MCAP log_time (ns since 1970), in s"
        if kinds <= {"log_time", "log_time (no header stamps)"}
        else "per topic: header stamp where present, else MCAP log_time, in s"
    )
    schema_of, encoding_of = topics.schema_of, topics.encoding_of
    ros = any(e == "cdr" for e in encoding_of.values())
    own = any(s.startswith("fsid") for s in schema_of.values()) or any(t.startswith("/fsid") for t in tables)
    info = {
        "time_base_by_topic": tb_by_topic,
        "schemas": schema_of,
        "encodings": encoding_of,
        "undecodable": topics.undecodable,
        "message_counts": dict(topics.counts),
        "map_hint": "fsid_mcap" if own or not ros else "ros2",
    }
    return RawLog(tables, "mcap", {}, [], desc, damage, info)


class _BadMessage(Exception):
    pass


def _decoder_for(ch, schema):
    enc = ch.message_encoding
    if enc == "json":
        return lambda data: json.loads(data)
    if enc == "cdr" and schema is not None:
        return Ros2DecoderFactory().decoder_for(enc, schema)
    if enc == "protobuf" and schema is not None:
        return ProtobufDecoderFactory().decoder_for(enc, schema)
    return None
