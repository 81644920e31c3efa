"""``fsid live`` measured: a simulated flight's telemetry (pipeline.outputs.writers.tlog)
replayed as fast as it goes (``fsid live --replay flight.tlog --speed max``) twice in one
process, its flight time over the replay's wall time (the goal: >= 50x real time), and the
update latency of a stream: the wall time from the last packet a read saw to the estimates
shown, over a real UDP socket on localhost at real time (``--stream-s`` seconds of the
flight).

    python benchmarks/live_replay.py [--scenario longitudinal_3211_calm] [--stream-s 20]

Measured (this machine): the 75 s flight replayed in 1.08 s (69x real time; the log's read
0.4 s of it) once the process has its imports and compiled kernels (the first replay of a
process 8.0 s); a 20 s stream at real time (7055 packets): update latency at most 0.30 s.
"""

from __future__ import annotations

import argparse
import json
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="longitudinal_3211_calm")
    ap.add_argument("--stream-s", type=float, default=20.0)
    args = ap.parse_args()
    import sim
    from pipeline.cli import main as fsid
    from pipeline.outputs.writers import write_truth_json
    from pipeline.outputs.writers.tlog import tlog_packets, write_tlog

    r = sim.fly(sim.load_scenario(ROOT / "scenarios" / f"{args.scenario}.toml"))
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        write_tlog(tmp / "flight.tlog", r)
        write_truth_json(tmp / "truth.json", r)
        for run in range(2):
            t0 = time.perf_counter()
            fsid(
                [
                    "live",
                    "--replay",
                    str(tmp / "flight.tlog"),
                    "--speed",
                    "max",
                    "--quiet",
                    "--out",
                    str(tmp / f"r{run}"),
                ]
            )
            wall = time.perf_counter() - t0
            doc = json.loads((tmp / f"r{run}" / "live.json").read_text())
            print(
                f"replay {run + 1}: {doc['flight_s']:.1f} s of flight in {wall:.2f} s wall "
                f"({doc['flight_s'] / wall:.0f}x real time; the loop alone {doc['wall_s']:.2f} s)"
            )
        ac = tmp / "ac.toml"
        ac.write_text(
            (ROOT / "scenarios" / "aircraft" / "uav_small.toml").read_text()
            + "\n[sensors.airdata]\nposition_m = [0.80, 0.0, 0.0]\n"
        )
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        cmd = [sys.executable, "-m", "pipeline.cli", "live", f"udpin:127.0.0.1:{port}", "--aircraft", str(ac)]
        proc = subprocess.Popen(
            [*cmd, "--idle", "2", "--out", str(tmp / "s")], stdout=subprocess.PIPE, text=True, cwd=ROOT
        )
        proc.stdout.readline()  # "receiving ...": the socket is open
        packets = [p for p in tlog_packets(r) if p[0] <= args.stream_s]
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            t0 = time.monotonic()
            for k, (t, b) in enumerate(packets):
                s.sendto(b, ("127.0.0.1", port))
                if k % 20 == 0 and t > time.monotonic() - t0:
                    time.sleep(t - (time.monotonic() - t0))
        proc.communicate(timeout=120)
        doc = json.loads((tmp / "s" / "live.json").read_text())
        print(
            f"stream: {doc['packets']} packets over {args.stream_s:g} s at real time; "
            f"update latency at most {doc['update_latency_s']:.3f} s"
        )


if __name__ == "__main__":
    main()
