"""Small synthetic logs written with the real formats, for tests, fuzzing and benchmarks.

``encode_dataflash`` writes ArduPilot DataFlash bytes (FMT records, then data records;
FMTU/UNIT/MULT optional); ``encode_tlog`` writes a MAVLink .tlog with pymavlink's own
encoders; ``write_json_mcap`` an MCAP with JSON topics using the mcap Writer.
"""

from __future__ import annotations

import json
import os
import struct
from collections.abc import Iterable, Sequence

import numpy as np
from mcap.writer import Writer

_STRUCT = {
    "a": "64s",
    "b": "b",
    "B": "B",
    "h": "h",
    "H": "H",
    "i": "i",
    "I": "I",
    "f": "f",
    "d": "d",
    "n": "4s",
    "N": "16s",
    "Z": "64s",
    "c": "h",
    "C": "H",
    "e": "i",
    "E": "I",
    "L": "i",
    "M": "b",
    "q": "q",
    "Q": "Q",
    "g": "e",
}


def fmt_record(mid: int, name: str, fmt: str, columns: Sequence[str]) -> bytes:
    """One FMT record (89 bytes) declaring message ``mid``."""
    length = 3 + struct.calcsize("<" + "".join(_STRUCT[c] for c in fmt))
    return struct.pack(
        "<BBBBB4s16s64s", 0xA3, 0x95, 0x80, mid, length, name.encode(), fmt.encode(), ",".join(columns).encode()
    )


def encode_dataflash(
    messages: dict[str, tuple[int, str, Sequence[str], np.ndarray]],
    order: str = "interleave",
    units: dict[str, tuple[str, str]] | None = None,
    params: dict[str, float] | None = None,
) -> bytes:
    """DataFlash bytes.

    messages : name -> (id, format chars, columns, rows) where rows is a structured-free
        (n, n_columns) array of *stored* values (ints for c/C/e/E/L, i.e. pre-multiplier).
    order : "interleave" sorts records by their first column (TimeUS) across types.
    units : name -> (unit id chars, multiplier id chars) for FMTU records (UNIT/MULT written).
    params : PARM records (TimeUS 0).
    """
    out = [fmt_record(0x80, "FMT", "BBnNZ", ["Type", "Length", "Name", "Format", "Columns"])]
    recs: list[tuple[float, bytes]] = []
    if params:
        out.append(fmt_record(0x40, "PARM", "QNf", ["TimeUS", "Name", "Value"]))
        for k, v in params.items():
            recs.append((0.0, struct.pack("<BBBQ16sf", 0xA3, 0x95, 0x40, 0, k.encode(), v)))
    if units:
        out.append(fmt_record(0x41, "UNIT", "QbZ", ["TimeUS", "Id", "Label"]))
        out.append(fmt_record(0x42, "MULT", "Qbd", ["TimeUS", "Id", "Mult"]))
        out.append(fmt_record(0x43, "FMTU", "QBNN", ["TimeUS", "FmtType", "UnitIds", "MultIds"]))
        for uid, lab in (("s", "s"), ("E", "rad/s"), ("o", "m/s/s"), ("d", "deg"), ("#", "instance"), ("-", "")):
            out.append(struct.pack("<BBBQb64s", 0xA3, 0x95, 0x41, 0, ord(uid), lab.encode()))
        for mid_, m in (("F", 1e-6), ("0", 1.0), ("-", 0.0), ("B", 1e-2)):
            out.append(struct.pack("<BBBQbd", 0xA3, 0x95, 0x42, 0, ord(mid_), m))
    for name, (mid, fmt, cols, rows) in messages.items():
        out.append(fmt_record(mid, name, fmt, cols))
        if units and name in units:
            u, m = units[name]
            out.append(struct.pack("<BBBQB16s16s", 0xA3, 0x95, 0x43, 0, mid, u.encode(), m.encode()))
        st = struct.Struct("<BBB" + "".join(_STRUCT[c] for c in fmt))
        for row in rows:
            vals = []
            for c, v in zip(fmt, row):
                if c in "nNZa":
                    vals.append(v if isinstance(v, bytes) else str(v).encode())
                elif c in "fdg":
                    vals.append(float(v))
                else:
                    vals.append(int(v))
            recs.append((float(row[0]), st.pack(0xA3, 0x95, mid, *vals)))
    if order == "interleave":
        recs.sort(key=lambda r: r[0])
    return b"".join(out) + b"".join(r for _, r in recs)


def demo_dataflash(n: int = 200, seed: int = 0, rate_hz: float = 50.0) -> bytes:
    """A small plane log: IMU (2 instances via FMTU), ATT, ARSP, AOA, BARO, RCOU, PARM, MODE."""
    rng = np.random.default_rng(seed)
    t = (np.arange(n) / rate_hz * 1e6).astype(np.int64) + 1_000_000
    imu = []
    for i in (0, 1):
        g = rng.normal(0, 0.1, (n, 3))
        a = rng.normal([0, 0, -9.81], 0.2, (n, 3))
        imu.append(np.column_stack([t + i, np.full(n, i), g, a]))
    imu_rows = np.concatenate(imu)
    att = np.column_stack(
        [
            t,
            np.round(rng.normal(0, 5, n) * 100),
            np.round(rng.normal(2, 1, n) * 100),
            np.round((np.arange(n) * 0.5 % 360) * 100),
        ]
    )
    arsp = np.column_stack([t, 20 + rng.normal(0, 0.3, n)])
    aoa = np.column_stack([t, 3 + rng.normal(0, 0.5, n), rng.normal(0, 0.5, n)])
    baro = np.column_stack([t, 100 + rng.normal(0, 0.2, n)])
    pwm = np.clip(1500 + np.round(rng.normal(0, 100, (n, 4))), 1000, 2000)
    rcou = np.column_stack([t, pwm])
    mode = np.array([[t[0], 5, 5], [t[n // 2], 0, 0]])
    params = {"SERVO1_FUNCTION": 4, "SERVO2_FUNCTION": 19, "SERVO3_FUNCTION": 70, "SERVO4_FUNCTION": 21}
    for k in range(1, 5):
        params.update({f"SERVO{k}_MIN": 1000, f"SERVO{k}_MAX": 2000, f"SERVO{k}_TRIM": 1500, f"SERVO{k}_REVERSED": 0})
    msgs = {
        "IMU": (0x10, "QBffffff", ["TimeUS", "I", "GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ"], imu_rows),
        "ATT": (0x11, "Qccc", ["TimeUS", "Roll", "Pitch", "Yaw"], att),
        "ARSP": (0x12, "Qf", ["TimeUS", "Airspeed"], arsp),
        "AOA": (0x13, "Qff", ["TimeUS", "AOA", "SSA"], aoa),
        "BARO": (0x14, "Qf", ["TimeUS", "Alt"], baro),
        "RCOU": (0x15, "QHHHH", ["TimeUS", "C1", "C2", "C3", "C4"], rcou),
        "MODE": (0x16, "QMB", ["TimeUS", "Mode", "ModeNum"], mode),
    }
    units = {"IMU": ("s#EEEooo", "F-000000"), "ATT": ("sddd", "FBBB")}
    return encode_dataflash(msgs, units=units, params=params)


def encode_tlog(n: int = 100, seed: int = 0, rate_hz: float = 20.0, t0: float = 1.7e9, autopilot: int = 3) -> bytes:
    """A small .tlog: HEARTBEAT (mode change half way), ATTITUDE, SCALED_IMU, VFR_HUD,
    SERVO_OUTPUT_RAW, PARAM_VALUE — encoded with pymavlink."""
    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink.dialects.v20 import ardupilotmega as mav

    rng = np.random.default_rng(seed)
    m = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    out = bytearray()

    def put(t: float, msg) -> None:
        out.extend(struct.pack(">Q", int(round(t * 1e6))))
        out.extend(msg.pack(m))

    for k, (pid, val) in enumerate(
        {"SERVO2_FUNCTION": 19.0, "SERVO2_MIN": 1000.0, "SERVO2_MAX": 2000.0, "SERVO2_TRIM": 1500.0}.items()
    ):
        put(t0, m.param_value_encode(pid.encode(), val, 9, 4, k))
    for i in range(n):
        t = t0 + i / rate_hz
        if i % 10 == 0:
            mode = 5 if i < n // 2 else 10  # FBWA then AUTO (ArduPlane)
            put(t, m.heartbeat_encode(1, autopilot, 81, mode, 4))
        put(
            t,
            m.attitude_encode(
                int(i * 1000 / rate_hz), 0.1 * np.sin(i / 10), 0.05, 1.0, float(rng.normal(0, 0.1)), 0.02, -0.01
            ),
        )
        put(t, m.scaled_imu_encode(int(i * 1000 / rate_hz), 10, -20, -1000, 5, -5, 100, 0, 0, 0))
        put(t, m.vfr_hud_encode(20.0 + 0.01 * i, 21.0, 90, 50, 100.0, 0.0))
        put(t, m.servo_output_raw_encode(int(i * 1e6 / rate_hz), 0, 1500, 1500 + (i % 20) * 10, 1100, 1500, 0, 0, 0, 0))
    return bytes(out)


def write_json_mcap(path: str | os.PathLike, topics: dict[str, Iterable[dict]]) -> None:
    """An MCAP with JSON messages; each message dict should hold ``t`` [s]."""
    with open(path, "wb") as fh:
        w = Writer(fh)
        w.start()
        for topic, msgs in topics.items():
            sid = w.register_schema(
                name=f"fsid{topic.replace('/', '.')}", encoding="jsonschema", data=b'{"type": "object"}'
            )
            cid = w.register_channel(topic=topic, message_encoding="json", schema_id=sid)
            for msg in msgs:
                ns = int(round(msg.get("t", 0.0) * 1e9))
                w.add_message(cid, log_time=ns, publish_time=ns, data=json.dumps(msg).encode())
        w.finish()


#: PX4 control surfaces (CA_SV_CS{k}_TYPE, _TRQ_R, _TRQ_P, _TRQ_Y; QGroundControl's defaults)
#: of the allocation layouts :func:`encode_ulog` can write
PX4_SURFACES = {
    "conventional": [(1, -0.5, 0.0, 0.0), (2, 0.5, 0.0, 0.0), (3, 0.0, 1.0, 0.0), (4, 0.0, 0.0, 1.0)],
    "elevons": [(5, -0.5, 0.5, 0.0), (6, 0.5, 0.5, 0.0)],
}


def px4_surface_commands(i: int) -> tuple[float, float, float]:
    """The normalised roll, pitch and yaw commands of sample i in :func:`encode_ulog`."""
    return 0.1, -0.2 * np.sin(i / 5), 0.3 * np.cos(i / 7)


def encode_ulog(n: int = 100, rate_hz: float = 100.0, seed: int = 0, allocation: str | None = None) -> bytes:
    """A minimal valid PX4 ULog: sensor_combined, vehicle_attitude, actuator_controls_0,
    vehicle_status; one parameter and sys_name info. ``allocation`` ("conventional" or
    "elevons", :data:`PX4_SURFACES`): PX4 1.14+ instead - no actuator_controls_0, the
    allocated surface commands in actuator_servos (control[k] = the surfaces' torque
    coefficients times :func:`px4_surface_commands`, the inverse of their allocation),
    the motor in actuator_motors (0.5) and the CA_SV_CS* parameters."""
    rng = np.random.default_rng(seed)
    surfaces = PX4_SURFACES[allocation] if allocation else None

    def msg(kind: bytes, payload: bytes) -> bytes:
        return struct.pack("<HB", len(payload), kind[0]) + payload

    out = bytearray(b"ULog\x01\x12\x35" + bytes([1]) + struct.pack("<Q", 0))
    out += msg(b"B", bytes(16) + struct.pack("<3Q", 0, 0, 0))
    key = b"char[4] sys_name"
    out += msg(b"I", bytes([len(key)]) + key + b"PX4\0")
    formats = {
        "sensor_combined": "uint64_t timestamp;float[3] gyro_rad;float[3] accelerometer_m_s2;",
        "vehicle_attitude": "uint64_t timestamp;float[4] q;",
        ("actuator_servos" if surfaces else "actuator_controls_0"): "uint64_t timestamp;float[8] control;",
        "vehicle_status": "uint64_t timestamp;uint8_t nav_state;uint8_t[7] _padding0;",
    }
    if surfaces:
        formats["actuator_motors"] = "uint64_t timestamp;float[4] control;"
    for name, f in formats.items():
        out += msg(b"F", f"{name}:{f}".encode())
    params = {"FW_AIRSPD_TRIM": 15.0}
    if surfaces:
        params["CA_SV_CS_COUNT"] = len(surfaces)
        for k, (typ, *trq) in enumerate(surfaces):
            params[f"CA_SV_CS{k}_TYPE"] = typ
            params.update({f"CA_SV_CS{k}_TRQ_{a}": v for a, v in zip("RPY", trq)})
    for name, v in params.items():
        if isinstance(v, int):
            key = f"int32_t {name}".encode()
            out += msg(b"P", bytes([len(key)]) + key + struct.pack("<i", v))
        else:
            key = f"float {name}".encode()
            out += msg(b"P", bytes([len(key)]) + key + struct.pack("<f", v))
    for k, name in enumerate(formats):
        out += msg(b"A", struct.pack("<BH", 0, k) + name.encode())
    for i in range(n):
        ts = 1_000_000 + int(i * 1e6 / rate_hz)
        g = rng.normal(0, 0.1, 3)
        a = rng.normal([0, 0, -9.81], 0.1, 3)
        out += msg(b"D", struct.pack("<HQ6f", 0, ts, *g, *a))
        yaw = 0.01 * i
        out += msg(b"D", struct.pack("<HQ4f", 1, ts, np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)))
        cmd = px4_surface_commands(i)
        if surfaces:
            # the surfaces' commands whose torque is cmd: u = B^+ cmd, B the coefficients
            B = np.array([trq for _, *trq in surfaces]).T  # (3, n_surfaces)
            u = np.linalg.pinv(B) @ np.array(cmd)
            out += msg(b"D", struct.pack("<HQ8f", 2, ts, *u, *np.zeros(8 - len(u))))
            out += msg(b"D", struct.pack("<HQ4f", 4, ts, 0.5, 0, 0, 0))  # motor 1 at half
        else:
            out += msg(b"D", struct.pack("<HQ8f", 2, ts, cmd[0], cmd[1], 0.0, 0.5, 0, 0, 0, 0))
        if i % 20 == 0:
            out += msg(b"D", struct.pack("<HQB7x", 3, ts, 0 if i < n // 2 else 3))
    return bytes(out)


def encode_px4_tlog(n: int = 60, rate_hz: float = 25.0, t0: float = 1.7e9) -> bytes:
    """A small PX4 .tlog: HEARTBEAT (autopilot 12, custom_mode of POSCTL), HIGHRES_IMU,
    ATTITUDE, ACTUATOR_CONTROL_TARGET, PARAM_VALUE (an INT32 parameter sent bytewise)."""
    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink.dialects.v20 import ardupilotmega as mav

    m = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    out = bytearray()

    def put(t: float, msg) -> None:
        out.extend(struct.pack(">Q", int(round(t * 1e6))))
        out.extend(msg.pack(m))

    as_float = struct.unpack("<f", struct.pack("<i", 1234))[0]  # PX4 sends int params bytewise
    put(t0, m.param_value_encode(b"SYS_AUTOSTART", as_float, mav.MAV_PARAM_TYPE_INT32, 2, 0))
    put(t0, m.param_value_encode(b"FW_AIRSPD_TRIM", 15.0, mav.MAV_PARAM_TYPE_REAL32, 2, 1))
    posctl = 3 << 16  # PX4 main mode 3 = POSCTL
    for i in range(n):
        t = t0 + i / rate_hz
        if i % 5 == 0:
            put(t, m.heartbeat_encode(1, 12, 81, posctl, 4))
        put(
            t,
            m.highres_imu_encode(
                int(i * 1e6 / rate_hz), 0.5, -0.25, -9.81, 0.01 * i, 0.02, -0.03, 0, 0, 0, 1013.0, 0, 0, 20.0, 0
            ),
        )
        put(t, m.attitude_encode(int(i * 1000 / rate_hz), 0.1, 0.05, 1.0, 0.0, 0.0, 0.0))
        put(t, m.actuator_control_target_encode(int(i * 1e6 / rate_hz), 0, [0.1, -0.2, 0.05, 0.6, 0, 0, 0, 0]))
    return bytes(out)
