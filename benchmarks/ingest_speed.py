"""Ingest speed: our DataFlash reader vs pymavlink's DFReader message loop.

Writes a >= 100 MB synthetic ArduPlane .bin: the simulator flies ``scenarios/default.toml``,
the sim's ``pipeline.outputs.writers.write_dataflash`` writes it (real ArduPlane layouts with
FMT/FMTU/UNIT/MULT/PARM), and its data records are repeated with TimeUS shifted by the
flight duration until the file reaches the size (a long flight made of repeated laps).
Without the simulator, a generator of the same layouts here is used. Then reads it with ``pipeline.ingest.readers.dataflash.message_arrays`` (in a subprocess, to
measure its peak memory) and with DFReader's ``recv_msg`` loop, checks identical values
(exact per-type counts; every field of every 20th message of every type) and prints the
speed ratio ours/DFReader last.

    python benchmarks/ingest_speed.py [--mb 100] [--keep PATH]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(HERE))

from pipeline.ingest.readers.synth import fmt_record  # noqa: E402

# ArduPlane 4.x layouts (name, id, format, columns)
LAYOUTS = [
    ("IMU", 0x10, "QBffffffIIfBBHH", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz"),
    ("ATT", 0x11, "QccccCCCCB", "TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw,ErrRP,ErrYaw,AEKF"),
    ("ARSP", 0x12, "QBffcffBBfB", "TimeUS,I,Airspeed,DiffPress,Temp,RawPress,Offset,U,H,Hp,Pri"),
    ("AOA", 0x13, "Qff", "TimeUS,AOA,SSA"),
    ("BARO", 0x14, "QBfffcfIffB", "TimeUS,I,Alt,AltAMSL,Press,Temp,CRt,SMS,Offset,GndTemp,H"),
    ("RCOU", 0x15, "QHHHHHHHHHHHHHH", "TimeUS,C1,C2,C3,C4,C5,C6,C7,C8,C9,C10,C11,C12,C13,C14"),
    ("GPS", 0x16, "QBBIHBcLLeffffB", "TimeUS,I,Status,GMS,GWk,NSats,HDop,Lat,Lng,Alt,Spd,GCrs,VZ,Yaw,U"),
]
NP = {
    "Q": "<u8",
    "B": "u1",
    "f": "<f4",
    "I": "<u4",
    "c": "<i2",
    "C": "<u2",
    "H": "<u2",
    "L": "<i4",
    "e": "<i4",
    "b": "i1",
    "h": "<i2",
    "i": "<i4",
}
# one "frame" = 4 ticks of a 200 Hz IMU (2 instances), plus 50 Hz ATT ARSP AOA RCOU, 10 Hz BARO/GPS
FRAME = ["IMU", "IMU", "IMU", "IMU", "IMU", "IMU", "IMU", "IMU", "ATT", "ARSP", "AOA", "RCOU", "BARO", "GPS"]


def _dtype(fmt: str, cols: str) -> np.dtype:
    return np.dtype([("h", "S3")] + [(c, NP[f]) for f, c in zip(fmt, cols.split(","))])


def write_synthetic_bin(path: Path, target_mb: float, seed: int = 0) -> int:
    """Write a DataFlash file of about ``target_mb`` MB; return the number of records."""
    rng = np.random.default_rng(seed)
    lay = {n: (mid, fmt, cols, _dtype(fmt, cols)) for n, mid, fmt, cols in LAYOUTS}
    parts = [fmt_record(0x80, "FMT", "BBnNZ", ["Type", "Length", "Name", "Format", "Columns"])]
    for n, (mid, fmt, cols, _dt) in lay.items():
        parts.append(fmt_record(mid, n, fmt, cols.split(",")))
    head = b"".join(parts)
    frame_dt = np.dtype([(f"m{k}", lay[n][3]) for k, n in enumerate(FRAME)])
    n_frames = int(target_mb * 1e6 / frame_dt.itemsize) + 1
    with open(path, "wb") as fh:
        fh.write(head)
        chunk = 200_000
        done = 0
        while done < n_frames:
            m = min(chunk, n_frames - done)
            fr = np.zeros(m, frame_dt)
            t0 = np.arange(done, done + m, dtype=np.int64) * 20_000 + 1_000_000  # 50 Hz frames
            for k, n in enumerate(FRAME):
                mid, fmt, cols, dt = lay[n]
                rec = fr[f"m{k}"]
                rec["h"] = bytes([0xA3, 0x95, mid])
                if n == "IMU":
                    tick, inst = divmod(k, 2)
                    rec["TimeUS"] = t0 + tick * 5000 + inst
                    rec["I"] = inst
                    for c in ("GyrX", "GyrY", "GyrZ"):
                        rec[c] = rng.normal(0, 0.2, m)
                    rec["AccX"], rec["AccY"] = rng.normal(0, 1, m), rng.normal(0, 1, m)
                    rec["AccZ"] = rng.normal(-9.81, 1, m)
                    rec["T"] = 45.0
                    rec["GHz"], rec["AHz"] = 800, 400
                else:
                    rec["TimeUS"] = t0 + 3
                    for c, f in zip(cols.split(",")[1:], fmt[1:]):
                        kind = np.dtype(NP[f]).kind
                        if kind == "f":
                            rec[c] = rng.normal(10, 5, m)
                        else:
                            info = np.iinfo(NP[f])
                            rec[c] = rng.integers(max(info.min, -30000), min(info.max, 30000), m)
            fh.write(fr.tobytes())
            done += m
    return n_frames * len(FRAME) + len(parts)


OURS = r"""
import json, resource, sys, time
sys.path.insert(0, {root!r})
from pipeline.ingest.readers.dataflash import message_arrays, _scan
import numpy as np
# compile once on a tiny buffer so timing is steady-state (numba caches to disk anyway)
_scan.walk(np.zeros(8, np.uint8), np.zeros(256, np.int64))
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
t = time.perf_counter()
arrays, formats, damage = message_arrays({path!r})
dt = time.perf_counter() - t
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
counts = {{k: int(v.shape[0]) for k, v in arrays.items()}}
del arrays
from pipeline.ingest.readers import read_log
t = time.perf_counter()
fd = read_log({path!r})
dt_fd = time.perf_counter() - t
peak_fd = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({{"seconds": dt, "peak_kb": peak, "base_kb": base, "seconds_flightdata": dt_fd,
                   "peak_kb_flightdata": peak_fd, "channels": len(fd.channels),
                   "counts": counts}}))
"""


def run_ours(path: Path) -> dict:
    code = OURS.format(root=str(HERE), path=str(path))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def run_dfreader(path: Path) -> tuple[float, dict]:
    from pymavlink import DFReader

    t = time.perf_counter()
    r = DFReader.DFReader_binary(str(path))
    counts: dict[str, int] = {}
    while True:
        m = r.recv_msg()
        if m is None:
            break
        name = m.get_type()
        counts[name] = counts.get(name, 0) + 1
    return time.perf_counter() - t, counts


def verify(path: Path, every: int = 20) -> int:
    """Compare every field of every ``every``-th message of each type; return how many."""
    from pymavlink import DFReader

    from pipeline.ingest.readers.dataflash import message_arrays, scaled

    arrays, formats, _ = message_arrays(path)
    by_name = {f.name: f for f in formats.values()}
    r = DFReader.DFReader_binary(str(path))
    seen: dict[str, int] = {}
    checked = 0
    while True:
        m = r.recv_msg()
        if m is None:
            break
        name = m.get_type()
        k = seen.get(name, 0)
        seen[name] = k + 1
        if name == "FMT" or k % every:
            continue
        for col in m.get_fieldnames():
            ours = scaled(arrays[name][k : k + 1], by_name[name], col)[0]
            theirs = getattr(m, col)
            if isinstance(ours, bytes):
                ours = ours.rstrip(b"\0").decode("ascii", "replace")
            if not (ours == theirs or (ours != ours and theirs != theirs)):
                raise SystemExit(f"MISMATCH {name}[{k}].{col}: ours {ours!r} DFReader {theirs!r}")
        checked += 1
    return checked


def write_sim_bin(path: Path, target_mb: float) -> int | None:
    """The sim's own writer, tiled to ``target_mb``; None when the simulator is unavailable."""
    try:
        from pipeline.ingest.readers.dataflash import scan_file
        from pipeline.outputs.writers import write_dataflash
        from sim import fly, load_scenario
    except ImportError:
        return None
    scen = HERE / "scenarios" / "default.toml"
    if not scen.is_file():
        return None
    res = fly(load_scenario(scen))
    one = path.with_suffix(".one.bin")
    write_dataflash(one, res)
    buf, formats, offs, ids, damage = scan_file(one)
    data = np.array(buf)
    del buf
    # the header: everything up to the first record with a TimeUS > 0 after the PARMs/FMTs
    meta_names = {"FMT", "FMTU", "UNIT", "MULT", "PARM", "MSG"}
    meta_ids = {k for k, f in formats.items() if f.name in meta_names}
    first_data = int(np.flatnonzero(~np.isin(ids, list(meta_ids)))[0])
    head_end = int(offs[first_data])
    body = data[head_end:]
    boffs = offs[first_data:] - head_end
    bids = ids[first_data:]
    # every data record here starts with TimeUS (uint64) right after the 3 header bytes
    ok = np.array([formats[int(i)].fmt.startswith("Q") for i in bids])
    tpos = (boffs[ok][:, None] + 3 + np.arange(8)).ravel()
    t_us = body[tpos].reshape(-1, 8).copy().view("<u8").ravel()
    span_us = int(t_us.max() - t_us.min()) + 10_000
    reps = int(np.ceil(target_mb * 1e6 / body.size))
    with open(path, "wb") as fh:
        fh.write(data[:head_end].tobytes())
        for k in range(reps):
            chunk = body.copy()
            chunk[tpos] = (t_us + np.uint64(k * span_us)).view(np.uint8)
            fh.write(chunk.tobytes())
    one.unlink()
    return int(first_data + reps * (ids.size - first_data))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mb", type=float, default=100.0, help="file size in MB (default 100)")
    ap.add_argument("--keep", default=None, help="write the .bin here and keep it")
    args = ap.parse_args()
    tmpdir = tempfile.mkdtemp(prefix="fsid-bench-")
    path = Path(args.keep) if args.keep else Path(tmpdir) / "synthetic.bin"
    t = time.perf_counter()
    n = write_sim_bin(path, args.mb)
    how = "sim flight (scenarios/default.toml) written by pipeline.outputs.writers.write_dataflash, tiled"
    if n is None:
        n = write_synthetic_bin(path, args.mb)
        how = "generator of ArduPlane IMU/ATT/ARSP/AOA/BARO/RCOU/GPS layouts (no simulator)"
    size = path.stat().st_size
    print(f"wrote {path}: {size / 1e6:.1f} MB, {n} records in {time.perf_counter() - t:.1f} s ({how})")
    ours = run_ours(path)
    print(
        f"ours     : {ours['seconds']:.2f} s  ({n / ours['seconds'] / 1e6:.2f} M records/s) all "
        "message types decoded to numpy arrays"
    )
    print(
        f"ours read_log -> FlightData ({ours['channels']} canonical SI channels, segments): "
        f"{ours['seconds_flightdata']:.2f} s, peak RSS {ours['peak_kb_flightdata'] * 1024 / 1e6:.0f} MB"
    )
    peak = (ours["peak_kb"] - ours["base_kb"]) * 1024
    print(
        f"ours peak memory of the read: {peak / 1e6:.0f} MB = {peak / size:.2f} x file size "
        f"(peak RSS {ours['peak_kb'] * 1024 / 1e6:.0f} MB minus {ours['base_kb'] * 1024 / 1e6:.0f} MB "
        "of interpreter + numpy/numba before reading; includes the mapped file pages)"
    )
    tdf, counts = run_dfreader(path)
    print(f"DFReader : {tdf:.2f} s  ({n / tdf / 1e6:.3f} M records/s)")
    mine = {k: v for k, v in ours["counts"].items()}
    if {k: v for k, v in counts.items() if k != "FMT"} != {k: v for k, v in mine.items() if k != "FMT"}:
        print(f"COUNT MISMATCH ours {mine} DFReader {counts}")
        return 1
    checked = verify(path)
    print(
        f"identical values: per-type counts equal ({sum(counts.values())} messages); every field "
        f"of {checked} sampled messages (every 20th of each type) equal"
    )
    ok = peak < 3 * size
    print(f"peak memory < 3 x file size: {'yes' if ok else 'NO'}")
    print(f"speed ratio read_log(FlightData)/DFReader: {tdf / ours['seconds_flightdata']:.1f}")
    print(f"speed ratio ours/DFReader: {tdf / ours['seconds']:.1f}")
    if not args.keep:
        path.unlink()
        os.rmdir(tmpdir)
    return 0


if __name__ == "__main__":
    sys.exit(main())
