"""A live MAVLink stream received into a .tlog as it arrives (``fsid live``).

The connection is pymavlink's (``udpin:0.0.0.0:14550``, ``udp:...``, ``tcp:host:port``, a
serial device ``/dev/ttyUSB0,57600``). Every packet received is appended at once to the
.tlog with its receive time (8-byte big-endian microseconds since the epoch, then the
packet: the format the ingest reads), and flushed, so that nothing received is lost when
the program stops; the flight data are read back from that file by the same ingest as any
log (:func:`pipeline.ingest.readers.read_log`).
"""

from __future__ import annotations

import os
import struct
import time
from pathlib import Path

from pipeline.errors import FsidError

#: what a source names: pymavlink connection strings the receiver accepts
SOURCE_PREFIXES = ("udpin:", "udpout:", "udp:", "udpbcast:", "tcp:", "tcpin:", "/dev/", "COM")


def _connect(source: str):
    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink import mavutil

    if not source.startswith(SOURCE_PREFIXES):
        raise FsidError(
            f"{source}: not a MAVLink source; give udpin:0.0.0.0:14550, tcp:HOST:PORT or a serial device "
            "(/dev/ttyUSB0,57600), or --replay LOG to replay a log file"
        )
    device, _, baud = source.partition(",")
    try:
        return mavutil.mavlink_connection(device, baud=int(baud) if baud else 57600, dialect="ardupilotmega")
    except (OSError, ValueError) as exc:
        raise FsidError(f"{source}: cannot open the MAVLink source ({exc}); check the address or device") from None


class MavlinkReceiver:
    """Packets from ``source`` appended to the .tlog at ``path`` as they arrive."""

    def __init__(self, source: str, path: str | Path) -> None:
        self.source = source
        self.path = Path(path)
        self.conn = _connect(source)
        self.fh = open(self.path, "ab")  # noqa: SIM115 - held open while receiving, closed by close()
        os.chmod(self.path, 0o644)
        self.packets = 0
        self.bad = 0
        self.last_receive: float | None = None

    def poll(self, duration: float) -> int:
        """Receive for up to ``duration`` seconds; returns the packets written."""
        end = time.monotonic() + duration
        n = 0
        while True:
            left = end - time.monotonic()
            if left <= 0:
                break
            msg = self.conn.recv_match(blocking=True, timeout=min(left, 0.05))
            if msg is None:
                continue
            if msg.get_type() == "BAD_DATA":
                self.bad += 1
                continue
            now = time.time()
            self.fh.write(struct.pack(">Q", int(now * 1e6)) + bytes(msg.get_msgbuf()))
            self.last_receive = now
            n += 1
        if n:
            self.fh.flush()
        self.packets += n
        return n

    def close(self) -> None:
        self.fh.flush()
        self.fh.close()
        self.conn.close()
