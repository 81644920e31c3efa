"""A simulated flight as MAVLink telemetry: the packets a ground station receives from an
ArduPlane (HEARTBEAT, PARAM_VALUE, HIGHRES_IMU, ATTITUDE, VFR_HUD, AOA_SSA,
SERVO_OUTPUT_RAW), encoded with pymavlink, and the same written as a .tlog (each packet
after its 8-byte big-endian receive time in microseconds since the epoch).

The channels are those of the DataFlash writer (:mod:`pipeline.outputs.writers.dataflash`):
the IMU, attitude and air-data sensors at their own rates, the commanded surfaces as servo
pulses of the same calibration, whose parameters (:func:`log_parameters`) are sent first.
``fsid live`` tests and replays receive these packets over a real socket.
"""

from __future__ import annotations

import os
import struct

import numpy as np

from pipeline.outputs.writers.dataflash import (
    THROTTLE_MAX_US,
    THROTTLE_MIN_US,
    THROTTLE_SPAN_US,
    _surface_outputs,
    log_parameters,
)
from pipeline.paths import atomic_write_bytes

#: the receive clock of the first packet (s since the epoch): a fixed date, so that a
#: flight's .tlog repeats byte for byte
EPOCH_T0 = 1.7e9
#: ArduPlane's HEARTBEAT: MAV_TYPE_FIXED_WING, MAV_AUTOPILOT_ARDUPILOTMEGA, FBWA (5)
_PLANE, _ARDUPILOT, _FBWA = 1, 3, 5


def _mavlink():
    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink.dialects.v20 import ardupilotmega as mav

    return mav.MAVLink(None, srcSystem=1, srcComponent=1)


def tlog_packets(result, tail: str = "conventional") -> list[tuple[float, bytes]]:
    """(flight time s, packet bytes) of ``result`` (a :class:`sim.SimResult`), in time
    order (parameters at time 0, then every sensor sample; HEARTBEAT at 1 Hz)."""
    m = _mavlink()
    travel = {a: result.aircraft.travel(a) for a in ("de", "da", "dr")}
    S, T = result.sensors, result.truth
    tt = T["t"].to_numpy()

    def truth(col: str, t: np.ndarray) -> np.ndarray:
        return np.interp(t, tt, T[col].to_numpy())

    out: list[tuple[float, int, bytes]] = []  # (time, order, packet): a stable time sort
    params = log_parameters(result, travel, "tas", tail)
    for k, (name, value) in enumerate(params.items()):
        out.append((0.0, 0, m.param_value_encode(name.encode(), float(value), 9, len(params), k).pack(m)))
    for t in np.arange(0.0, tt[-1], 1.0):
        out.append((float(t), 1, m.heartbeat_encode(_PLANE, _ARDUPILOT, 81, _FBWA, 4).pack(m)))
    imu = S["imu"]
    for t, ax, ay, az, p, q, r in imu[["t", "ax", "ay", "az", "p", "q", "r"]].itertuples(index=False):
        msg = m.highres_imu_encode(int(round(t * 1e6)), ax, ay, az, p, q, r, 0.0, 0.0, 0.0, 1013.0, 0.0, 0.0, 25.0, 63)
        out.append((float(t), 2, msg.pack(m)))
    att = S["attitude"]
    for t, phi, theta, psi in att[["t", "phi", "theta", "psi"]].itertuples(index=False):
        msg = m.attitude_encode(int(round(t * 1000)), phi, theta, psi, 0.0, 0.0, 0.0)
        out.append((float(t), 3, msg.pack(m)))
    ad = S["airdata"]
    td = ad["t"].to_numpy()
    h, thr = truth("h", td), truth("throttle", td)
    for k, (t, V, alpha, beta) in enumerate(ad[["t", "V", "alpha", "beta"]].itertuples(index=False)):
        out.append((float(t), 4, m.vfr_hud_encode(V, V, 0, int(round(100 * thr[k])), h[k], 0.0).pack(m)))
        out.append((float(t), 5, m.aoa_ssa_encode(int(round(t * 1e6)), np.degrees(alpha), np.degrees(beta)).pack(m)))
    ts = S["surfaces"]["t"].to_numpy()
    lim = result.aircraft.limits
    de, da, dr = (np.clip(truth(f"{a}_cmd", ts), -lim[a], lim[a]) for a in ("de", "da", "dr"))
    pwm = _surface_outputs(tail, de, da, dr, travel)
    c3 = np.clip(np.round(THROTTLE_MIN_US + THROTTLE_SPAN_US * truth("throttle", ts)), THROTTLE_MIN_US, THROTTLE_MAX_US)
    for k, t in enumerate(ts):
        servos = [int(pwm["C1"][k]), int(pwm["C2"][k]), int(c3[k]), int(pwm["C4"][k])] + [0] * 4
        msg = m.servo_output_raw_encode(int(round(t * 1e6)) & 0xFFFFFFFF, 0, *servos)
        out.append((float(t), 6, msg.pack(m)))
    out.sort(key=lambda r: (r[0], r[1]))
    return [(t, b) for t, _, b in out]


def write_tlog(path: str | os.PathLike, result, tail: str = "conventional") -> None:
    """Write ``result``'s telemetry (:func:`tlog_packets`) as a .tlog (atomic), received
    from EPOCH_T0 on the flight's own clock."""
    body = b"".join(struct.pack(">Q", int(round((EPOCH_T0 + t) * 1e6))) + b for t, b in tlog_packets(result, tail))
    atomic_write_bytes(path, body)
