"""ArduPilot DataFlash (.bin) writer with the real ArduPlane message layouts.

Layouts (format chars, labels, units, multipliers) are those of ArduPilot's
``AP_Logger/LogStructure.h``, ``AP_InertialSensor``, ``AP_AHRS``, ``AP_Baro``, ``AP_GPS``,
``AP_NavEKF3`` and ``ArduPlane/Log.cpp`` (4.x): FMT, UNIT, MULT, FMTU, PARM, MSG, IMU,
ATT, ARSP, AOA, BARO, RCOU, GPS, CTUN, XKF1. Records are written in time order, TimeUS
= round(t * 1e6) with t the simulation time (the log starts at boot, t = 0).

What each message carries (sensor tables of the flight, see ``sim.sensors``):

* IMU (I = 0): the IMU sensor (rad/s, m/s^2).  ATT: the attitude sensor (deg, Yaw 0..360).
* ARSP.Airspeed: the measured *true* airspeed (``airspeed="tas"``, default, what the
  built-in ardupilot_bin channel map expects today). Real ArduPilot logs the *equivalent*
  airspeed there; ``airspeed="eas"`` writes EAS = V_meas * sqrt(rho/1.225) instead. Either
  way CTUN.E2T holds the EAS-to-TAS ratio, so TAS = EAS * CTUN.E2T.
* AOA.AOA / AOA.SSA: the boom vanes' alpha and beta (deg). A real ArduPilot log holds its
  AHRS estimate there (EKF velocity minus its wind); the built-in map marks them
  ``derived``, so ``fsid estimate`` rebuilds the angles from the flight path instead
  (pipeline.conditioning.flow_angles) - read the vanes from flight.mcap.
* BARO.Alt: the barometric altitude sensor (m above sea level, Offset 0); Press, Temp ISA.
* RCOU: servo PWM of the *commanded* deflections (truth ``*_cmd``, the autopilot's output)
  at the surfaces-sensor rate, integer microseconds. Channels and PARM calibration:
  C1 aileron (SERVO1_FUNCTION 4), C2 elevator (19), C3 throttle (70), C4 rudder (21)
  (``tail="elevons"``: C1/C2 elevon left/right (77/78); ``"vtail"``: C2/C4 V-tail left/right
  (79/80), mixed as ArduPilot mixes them - the same flight for the reader's mixing);
  surfaces MIN 1100 / TRIM 1500 / MAX 1900, REVERSED 0, full travel (MAX - TRIM) = the
  aircraft's ``[servos]`` travel of that surface (default 30 deg; also logged as PARM
  ``FSID_TRAVEL_DE`` / ``_DA`` / ``_DR``, which the built-in map reads). The sim flies
  whole-microsecond commands of those servos, so RCOU holds exactly what was flown (with
  continuous commands, scenario ``[actuators] pwm_servos = false``, RCOU rounds them:
  0.075 deg steps at 30 deg). ArduPilot's
  convention: PWM above trim = roll right / pitch up / yaw right, so
  da = +x*travel, de = -x*travel, dr = -x*travel with x = (PWM - TRIM)/(MAX - TRIM)
  (de > 0 trailing edge down, dr > 0 trailing edge left). Throttle: MIN 1000, MAX 2000,
  throttle = (PWM - 1000)/1000.
* GPS / XKF1: the GPS sensor velocities (NED) and altitude; XKF1 also the attitude.
* CTUN: roll, pitch (centideg), ThO throttle (%), As/SAs airspeed (EAS), E2T.
* PARM FSID_MAX_THRUST: the thrust model's maximum (N); thrust = throttle * FSID_MAX_THRUST
  along body x (ArduPilot has no thrust message).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd

from pipeline.paths import atomic_write_bytes
from sim.aircraft import SERVO_SPAN_US
from sim.scenario import THROTTLE_SPAN_US

#: surface servo PWM: trim (neutral) and the ends of travel, microseconds; throttle PWM range
SERVO_TRIM_US = 1500
SERVO_MIN_US, SERVO_MAX_US = SERVO_TRIM_US - SERVO_SPAN_US, SERVO_TRIM_US + SERVO_SPAN_US
THROTTLE_MIN_US, THROTTLE_MAX_US = 1000, 1000 + THROTTLE_SPAN_US

RHO0 = 1.225
_DT = {
    "b": "i1",
    "B": "u1",
    "h": "<i2",
    "H": "<u2",
    "i": "<i4",
    "I": "<u4",
    "f": "<f4",
    "d": "<f8",
    "n": "S4",
    "N": "S16",
    "Z": "S64",
    "c": "<i2",
    "C": "<u2",
    "e": "<i4",
    "E": "<u4",
    "L": "<i4",
    "M": "u1",
    "q": "<i8",
    "Q": "<u8",
}


@dataclass(frozen=True)
class MsgDef:
    id: int
    name: str
    fmt: str
    labels: str
    units: str
    mults: str

    @property
    def dtype(self) -> np.dtype:
        cols = self.labels.split(",")
        return np.dtype([("h1", "u1"), ("h2", "u1"), ("id", "u1")] + [(c, _DT[f]) for c, f in zip(cols, self.fmt)])


MSGS = {
    m.name: m
    for m in [
        MsgDef(128, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns", "-b---", "-----"),
        MsgDef(177, "UNIT", "QbZ", "TimeUS,Id,Label", "s--", "F--"),
        MsgDef(178, "FMTU", "QBNN", "TimeUS,FmtType,UnitIds,MultIds", "s---", "F---"),
        MsgDef(179, "MULT", "Qbd", "TimeUS,Id,Mult", "s--", "F--"),
        MsgDef(64, "PARM", "QNff", "TimeUS,Name,Value,Default", "s---", "F---"),
        MsgDef(91, "MSG", "QZ", "TimeUS,Message", "s-", "F-"),
        MsgDef(
            20,
            "IMU",
            "QBffffffIIfBBHH",
            "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz",
            "s#EEEooo--O--zz",
            "F-000000-----00",
        ),
        MsgDef(21, "ATT", "QffffffB", "TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw,AEKF", "sddddhh-", "F000000-"),
        MsgDef(
            22,
            "ARSP",
            "QBffcffBBffB",
            "TimeUS,I,Airspeed,DiffPress,Temp,RawPress,Offset,U,H,Hp,TR,Pri",
            "s#nPOPP-----",
            "F-00B00-----",
        ),
        MsgDef(23, "AOA", "Qff", "TimeUS,AOA,SSA", "sdd", "F00"),
        MsgDef(
            24,
            "BARO",
            "QBffcfIffB",
            "TimeUS,I,Alt,Press,Temp,CRt,SMS,Offset,GndTemp,Health",
            "s#mPOnsmO-",
            "F-00B0C?0-",
        ),
        MsgDef(
            25,
            "RCOU",
            "QHHHHHHHHHHHHHH",
            "TimeUS,C1,C2,C3,C4,C5,C6,C7,C8,C9,C10,C11,C12,C13,C14",
            "sYYYYYYYYYYYYYY",
            "F--------------",
        ),
        MsgDef(
            26,
            "GPS",
            "QBBIHBcLLeffffB",
            "TimeUS,I,Status,GMS,GWk,NSats,HDop,Lat,Lng,Alt,Spd,GCrs,VZ,Yaw,U",
            "s#---SmDUmnhnh-",
            "F----0BGGB000--",
        ),
        MsgDef(
            27,
            "CTUN",
            "Qccccffffffi",
            "TimeUS,NavRoll,Roll,NavPitch,Pitch,ThO,RdrOut,ThD,As,SAs,E2T,GU",
            "sdddd---nn-n",
            "FBBBB---00-B",
        ),
        MsgDef(
            28,
            "XKF1",
            "QBccCfffffffccce",
            "TimeUS,C,Roll,Pitch,Yaw,VN,VE,VD,dPD,PN,PE,PD,GX,GY,GZ,OH",
            "s#ddhnnnnmmmkkkm",
            "F-BBB0000000BBBB",
        ),
    ]
}
UNITS = {
    "-": "",
    "?": "UNKNOWN",
    "#": "instance",
    "b": "B",
    "d": "deg",
    "D": "deglatitude",
    "E": "rad/s",
    "h": "degheading",
    "k": "deg/s",
    "m": "m",
    "n": "m/s",
    "o": "m/s/s",
    "O": "degC",
    "P": "Pa",
    "s": "s",
    "S": "satellites",
    "U": "deglongitude",
    "Y": "us",
    "z": "Hz",
}
MULTS = {"-": 0.0, "?": 1.0, "0": 1.0, "B": 1e-2, "C": 1e-3, "F": 1e-6, "G": 1e-7}


def _records(name: str, n: int, **cols) -> np.ndarray:
    m = MSGS[name]
    a = np.zeros(n, dtype=m.dtype)
    a["h1"], a["h2"], a["id"] = 0xA3, 0x95, m.id
    for k, v in cols.items():
        a[k] = v
    return a


def _isa(h: np.ndarray, rho: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """ISA temperature (K) at altitude h (m) and the pressure (Pa) matching density rho."""
    T = 288.15 - 0.0065 * h
    return T, rho * 287.05287 * T


def _at(df: pd.DataFrame, col: str, t: np.ndarray) -> np.ndarray:
    return np.interp(t, df["t"].to_numpy(), df[col].to_numpy())


def _pwm_of(x: np.ndarray) -> np.ndarray:
    """Whole-microsecond servo pulses of normalised outputs x (-1..1 about trim)."""
    return np.clip(np.round(SERVO_TRIM_US + SERVO_SPAN_US * x), SERVO_MIN_US, SERVO_MAX_US)


#: servo outputs of the tail layouts: output -> SERVOn_FUNCTION (ArduPilot: 4 aileron,
#: 19 elevator, 21 rudder, 70 throttle, 77/78 elevon left/right, 79/80 V-tail left/right)
TAILS = {
    "conventional": {1: 4, 2: 19, 3: 70, 4: 21},
    "elevons": {1: 77, 2: 78, 3: 70, 4: 21},
    "vtail": {1: 4, 2: 79, 3: 70, 4: 80},
}


def _surface_outputs(
    tail: str, de: np.ndarray, da: np.ndarray, dr: np.ndarray, travel: Mapping[str, float]
) -> dict[str, np.ndarray]:
    """RCOU C1, C2, C4 pulses of the flown deflections (rad) in the tail layout. ArduPilot's
    normalised commands: elevator e = -de / travel (pitch up, trailing edge up), aileron
    a = da / travel, rudder r = -dr / travel; mixed outputs as its channel_function_mixer
    with the surfaces' physical deflections: elevon left e - a, right e + a; V-tail left
    e + r, right e - r (the reader's pipeline.ingest.maps ``mix`` inverts them)."""
    e, a, r = -de / travel["de"], da / travel["da"], -dr / travel["dr"]
    if tail == "elevons":
        return {"C1": _pwm_of(e - a), "C2": _pwm_of(e + a), "C4": _pwm_of(r)}
    if tail == "vtail":
        return {"C1": _pwm_of(a), "C2": _pwm_of(e + r), "C4": _pwm_of(e - r)}
    return {"C1": _pwm_of(a), "C2": _pwm_of(e), "C4": _pwm_of(r)}


def write_dataflash(path: str | os.PathLike, result, airspeed: str = "tas", tail: str = "conventional") -> None:
    """Write ``result`` (a :class:`sim.SimResult`) as an ArduPilot DataFlash log (atomic).

    airspeed: "tas" (default) or "eas" (ArduPilot's own semantics) for ARSP.Airspeed.
    The servo travel of each surface is the flight's (``result.aircraft.travel``).
    tail: the servo layout the same deflections are written in (:data:`TAILS`):
    "conventional" (aileron, elevator, throttle, rudder on outputs 1-4), "elevons" (the
    elevator and aileron mixed on outputs 1/2, a flying wing's) or "vtail" (elevator and
    rudder mixed on outputs 2/4).
    """
    if airspeed not in ("eas", "tas"):
        raise ValueError(f"airspeed must be 'eas' or 'tas', got {airspeed!r}")
    if tail not in TAILS:
        raise ValueError(f"tail must be one of {', '.join(TAILS)}, got {tail!r}")
    travel = {a: result.aircraft.travel(a) for a in ("de", "da", "dr")}  # rad
    log = _Log(result)
    _imu_attitude(log)
    _air_data(log, airspeed)
    _baro(log)
    _servos(log, tail, travel)
    _gps_ekf(log)
    _ctun(log, travel)
    head = _header(result, travel, airspeed, tail)
    atomic_write_bytes(path, head + _interleave(log.blocks))


class _Log:
    """The records of a DataFlash log being written from a flight ``result``: blocks of
    one message type each with their TimeUS, in the order added (records at the same time
    keep that order); the flight's sensor tables ``S`` and truth table ``T``."""

    def __init__(self, result) -> None:
        self.result = result
        self.S, self.T = result.sensors, result.truth
        self.tt = self.T["t"].to_numpy()
        self.blocks: list[tuple[np.ndarray, np.ndarray]] = []  # (TimeUS, records)

    def add(self, name: str, t: np.ndarray, **cols) -> None:
        us = np.round(np.asarray(t) * 1e6).astype(np.uint64)
        self.blocks.append((us, _records(name, len(us), TimeUS=us, **cols)))

    def truth_at(self, col: str, t: np.ndarray) -> np.ndarray:
        return np.interp(t, self.tt, self.T[col].to_numpy())


def _imu_attitude(log: _Log) -> None:
    """IMU (the IMU sensor) and ATT (the attitude sensor) records."""
    imu = log.S["imu"]
    ti = imu["t"].to_numpy()
    rate = log.result.meta["sensors"]["imu"]["rate_hz"]
    log.add(
        "IMU",
        ti,
        I=0,
        GyrX=imu["p"],
        GyrY=imu["q"],
        GyrZ=imu["r"],
        AccX=imu["ax"],
        AccY=imu["ay"],
        AccZ=imu["az"],
        T=25.0,
        GH=1,
        AH=1,
        GHz=int(round(rate)),
        AHz=int(round(rate)),
    )
    att = log.S["attitude"]
    ta = att["t"].to_numpy()
    roll, pitch = np.rad2deg(att["phi"].to_numpy()), np.rad2deg(att["theta"].to_numpy())
    yaw = np.mod(np.rad2deg(att["psi"].to_numpy()), 360.0)
    log.add("ATT", ta, Roll=roll, Pitch=pitch, Yaw=yaw, DesYaw=yaw, AEKF=3)


def _air_data(log: _Log, airspeed: str) -> None:
    """ARSP (the measured airspeed, TAS or EAS) and AOA (the vanes) records."""
    ad = log.S["airdata"]
    td = ad["t"].to_numpy()
    e2t_d = np.sqrt(RHO0 / log.truth_at("rho", td))
    v_as = ad["V"].to_numpy() / (e2t_d if airspeed == "eas" else 1.0)
    Tk, p = _isa(log.truth_at("h", td), log.truth_at("rho", td))
    log.add(
        "ARSP",
        td,
        I=0,
        Airspeed=v_as,
        DiffPress=0.5 * RHO0 * (ad["V"].to_numpy() / e2t_d) ** 2,
        Temp=np.round((Tk - 273.15) * 100),
        RawPress=0.5 * RHO0 * (ad["V"].to_numpy() / e2t_d) ** 2,
        Offset=0.0,
        U=1,
        H=1,
        Hp=1.0,
        TR=0.0,
        Pri=0,
    )
    log.add("AOA", td, AOA=np.rad2deg(ad["alpha"].to_numpy()), SSA=np.rad2deg(ad["beta"].to_numpy()))


def _baro(log: _Log) -> None:
    """BARO records: the barometric altitude, ISA pressure and temperature."""
    ba = log.S["baro"]
    tb = ba["t"].to_numpy()
    Tk, p = _isa(log.truth_at("h", tb), log.truth_at("rho", tb))
    log.add(
        "BARO",
        tb,
        I=0,
        Alt=ba["h"],
        Press=p,
        Temp=np.round((Tk - 273.15) * 100),
        CRt=-log.truth_at("vd", tb),
        SMS=np.round(tb * 1000).astype(np.uint32),
        Offset=0.0,
        GndTemp=15.0,
        Health=1,
    )


def _servos(log: _Log, tail: str, travel: Mapping[str, float]) -> None:
    """RCOU records: the commanded deflections as servo pulses in the ``tail`` layout."""
    ts = log.S["surfaces"]["t"].to_numpy()
    lim = log.result.aircraft.limits
    de = np.clip(log.truth_at("de_cmd", ts), -lim["de"], lim["de"])
    da = np.clip(log.truth_at("da_cmd", ts), -lim["da"], lim["da"])
    dr = np.clip(log.truth_at("dr_cmd", ts), -lim["dr"], lim["dr"])
    thr = log.truth_at("throttle", ts)
    rc = {f"C{k}": 0 for k in range(5, 15)}
    log.add(
        "RCOU",
        ts,
        **_surface_outputs(tail, de, da, dr, travel),
        C3=np.clip(np.round(THROTTLE_MIN_US + THROTTLE_SPAN_US * thr), THROTTLE_MIN_US, THROTTLE_MAX_US),
        **rc,
    )


def _gps_ekf(log: _Log) -> None:
    """GPS records (the GPS sensor) and XKF1 (its velocities, the attitude, positions)."""
    T, tt = log.T, log.tt
    att = log.S["attitude"]
    ta = att["t"].to_numpy()
    gp = log.S["gps"]
    tg = gp["t"].to_numpy()
    vn, ve, vd = (gp[c].to_numpy() for c in ("vn", "ve", "vd"))
    log.add(
        "GPS",
        tg,
        I=0,
        Status=3,
        GMS=(np.round(tg * 1000).astype(np.int64) + 345_600_000) % 604_800_000,
        GWk=2300,
        NSats=12,
        HDop=80,
        Lat=np.round(log.truth_at("lat", tg) * 1e7),
        Lng=np.round(log.truth_at("lon", tg) * 1e7),
        Alt=np.round(gp["h"].to_numpy() * 100),
        Spd=np.hypot(vn, ve),
        GCrs=np.mod(np.rad2deg(np.arctan2(ve, vn)), 360.0),
        VZ=vd,
        Yaw=0.0,
        U=1,
    )
    pn = np.concatenate([[0.0], np.cumsum(0.5 * (T["vn"].to_numpy()[1:] + T["vn"].to_numpy()[:-1]) * np.diff(tt))])
    pe = np.concatenate([[0.0], np.cumsum(0.5 * (T["ve"].to_numpy()[1:] + T["ve"].to_numpy()[:-1]) * np.diff(tt))])
    log.add(
        "XKF1",
        tg,
        C=0,
        Roll=np.round(_at(att, "phi", tg) * 18000 / np.pi),
        Pitch=np.round(_at(att, "theta", tg) * 18000 / np.pi),
        Yaw=np.round(np.mod(np.rad2deg(np.unwrap(np.interp(tg, ta, np.unwrap(att["psi"].to_numpy())))), 360.0) * 100)
        % 36000,
        VN=vn,
        VE=ve,
        VD=vd,
        dPD=vd,
        PN=np.interp(tg, tt, pn),
        PE=np.interp(tg, tt, pe),
        PD=-(gp["h"].to_numpy() - log.result.trim["h"]),
        GX=0,
        GY=0,
        GZ=0,
        OH=0,
    )


def _ctun(log: _Log, travel: Mapping[str, float]) -> None:
    """CTUN records at the attitude's times: attitude, throttle, rudder, EAS and E2T."""
    att, ad = log.S["attitude"], log.S["airdata"]
    ta, td = att["t"].to_numpy(), ad["t"].to_numpy()
    roll, pitch = np.rad2deg(att["phi"].to_numpy()), np.rad2deg(att["theta"].to_numpy())
    e2t_a = np.sqrt(RHO0 / log.truth_at("rho", ta))
    eas_a = np.interp(ta, td, ad["V"].to_numpy()) / e2t_a
    log.add(
        "CTUN",
        ta,
        Roll=np.round(roll * 100),
        Pitch=np.round(pitch * 100),
        ThO=100 * log.truth_at("throttle", ta),
        RdrOut=-4500 * log.truth_at("dr_cmd", ta) / travel["dr"],
        ThD=100 * log.truth_at("throttle", ta),
        As=eas_a,
        SAs=eas_a,
        E2T=e2t_a,
        GU=0,
    )


def _interleave(blocks: list[tuple[np.ndarray, np.ndarray]]) -> bytes:
    """The records of all blocks (TimeUS, records) in time order, ties in block order, as
    one byte string: every record is copied to its place in one array (no loop over records)."""
    times = np.concatenate([b[0] for b in blocks])
    which = np.concatenate([np.full(len(b[0]), i) for i, b in enumerate(blocks)])
    index = np.concatenate([np.arange(len(b[0])) for b in blocks])
    order = np.lexsort((which, times))
    which, index = which[order], index[order]
    size = np.array([b[1].dtype.itemsize for b in blocks], dtype=np.int64)
    length = size[which]
    start = np.cumsum(length) - length  # byte offset of each record in the body
    body = np.empty(int(length.sum()), dtype=np.uint8)
    for i, (_, rec) in enumerate(blocks):
        mine = which == i
        raw = np.frombuffer(rec.tobytes(), dtype=np.uint8).reshape(len(rec), size[i])
        body[start[mine][:, None] + np.arange(size[i])] = raw[index[mine]]
    return body.tobytes()


def log_parameters(result, travel: Mapping[str, float], airspeed: str = "tas", tail: str = "conventional") -> dict:
    """The autopilot parameters a simulated flight's log carries (name -> value): the servo
    functions and calibration of the ``tail`` layout, the surfaces' travel (FSID_TRAVEL_*,
    deg), the thrust model, the airspeed's kind, the IMU position."""
    params = {f"SERVO{k}_FUNCTION": fn for k, fn in TAILS[tail].items()}
    for k in (1, 2, 4):
        params.update(
            {
                f"SERVO{k}_MIN": SERVO_MIN_US,
                f"SERVO{k}_MAX": SERVO_MAX_US,
                f"SERVO{k}_TRIM": SERVO_TRIM_US,
                f"SERVO{k}_REVERSED": 0,
            }
        )
    params.update(
        {
            "SERVO3_MIN": THROTTLE_MIN_US,
            "SERVO3_MAX": THROTTLE_MAX_US,
            "SERVO3_TRIM": THROTTLE_MIN_US,
            "SERVO3_REVERSED": 0,
            **{f"FSID_TRAVEL_{a.upper()}": float(np.rad2deg(v)) for a, v in travel.items()},
            "FSID_MAX_THRUST": result.aircraft.max_thrust,
            "FSID_ARSP_TAS": 1.0 if airspeed == "tas" else 0.0,
            "AHRS_EKF_TYPE": 3,
        }
    )
    imu = getattr(result.scenario, "sensors", {}).get("imu")
    if imu is not None:  # ArduPilot's IMU position from the CG (body axes, m)
        params.update(zip(("INS_POS1_X", "INS_POS1_Y", "INS_POS1_Z"), (float(v) for v in imu.position)))
    return params


def _header(result, travel: dict[str, float], airspeed: str, tail: str = "conventional") -> bytes:
    out = []
    for m in MSGS.values():
        length = m.dtype.itemsize
        out.append(
            _records(
                "FMT",
                1,
                Type=m.id,
                Length=length,
                Name=m.name.encode(),
                Format=m.fmt.encode(),
                Columns=m.labels.encode(),
            ).tobytes()
        )
    for uid, lab in UNITS.items():
        out.append(_records("UNIT", 1, TimeUS=0, Id=ord(uid), Label=lab.encode()).tobytes())
    for mid, mult in MULTS.items():
        out.append(_records("MULT", 1, TimeUS=0, Id=ord(mid), Mult=mult).tobytes())
    for m in MSGS.values():
        out.append(
            _records("FMTU", 1, TimeUS=0, FmtType=m.id, UnitIds=m.units.encode(), MultIds=m.mults.encode()).tobytes()
        )
    params = log_parameters(result, travel, airspeed, tail)
    for k, v in params.items():
        out.append(_records("PARM", 1, TimeUS=0, Name=k.encode(), Value=float(v), Default=float(v)).tobytes())
    notes = [
        f"fsid sim: scenario {result.scenario.name} seed {result.meta['seed']}",
        f"fsid sim: aircraft {result.aircraft.name}",
        "fsid sim: servo travel (deg at PWM MAX-TRIM) "
        + " ".join(f"{a} {np.rad2deg(v):.4g}" for a, v in travel.items()),
        f"fsid sim: ARSP.Airspeed is {airspeed.upper()}; TAS = EAS * CTUN.E2T",
        "fsid sim: thrust = throttle * FSID_MAX_THRUST (N) along body x",
    ]
    for n in notes:
        out.append(_records("MSG", 1, TimeUS=0, Message=n.encode()[:64]).tobytes())
    return b"".join(out)
