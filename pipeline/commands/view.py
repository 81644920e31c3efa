"""``fsid view RUN_DIR``: open the folder's recording in the rerun viewer: ``run.rrd``
(``fsid run`` / ``estimate`` / ``demo``), else ``check.rrd`` (``fsid check``).

With a display (``DISPLAY`` or ``WAYLAND_DISPLAY`` set) the native viewer opens; otherwise
(or with ``--web``) rerun's own web viewer is served on localhost and the address printed:
``rerun RUN.rrd --serve-web --bind 127.0.0.1 --web-viewer-port W --port G``. The command
runs until the viewer closes or Ctrl-C. RUN_DIR may also be the .rrd file itself.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import socket
import subprocess
import sys
from collections.abc import Mapping
from pathlib import Path
from urllib.parse import quote

from pipeline.errors import FsidError

HELP = "open a run's or a check's recording (run.rrd, check.rrd) in the rerun viewer, or serve the web viewer"
#: the recordings a folder may hold, the one opened first
RECORDINGS = ("run.rrd", "check.rrd")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "run_dir",
        metavar="RUN_DIR",
        help="folder written by 'fsid run/estimate/demo' (run.rrd) or 'fsid check' (check.rrd), or a .rrd file",
    )
    parser.add_argument("--web", action="store_true", help="serve the web viewer even when a display is available")
    parser.add_argument(
        "--bind", default="127.0.0.1", help="address the web viewer listens on (default: 127.0.0.1, this machine only)"
    )
    parser.add_argument(
        "--web-port", type=int, default=9090, help="HTTP port of the web viewer (default 9090; 0 picks a free one)"
    )
    parser.add_argument(
        "--grpc-port",
        type=int,
        default=9876,
        help="gRPC port the web viewer reads the recording from (default 9876; 0 picks a free one)",
    )


def rrd_path(run_dir: str | os.PathLike) -> Path:
    """The recording of a run or check folder (run.rrd, else check.rrd) or the given .rrd,
    or FsidError saying what to do."""
    p = Path(run_dir)
    if p.suffix == ".rrd":
        if p.is_file():
            return p
        raise FsidError(f"recording '{p}' not found; give a folder written by 'fsid run', 'fsid check' or 'fsid demo'")
    if not p.exists():
        raise FsidError(
            f"run folder '{p}' not found; give the folder that 'fsid run', 'fsid check' or 'fsid demo' printed"
        )
    found = [p / name for name in RECORDINGS if (p / name).is_file()]
    if found:
        return found[0]
    if (p / "checks.json").is_file():
        raise FsidError(
            f"no recording in '{p}' (no run.rrd or check.rrd): its checks.json was written before "
            f"'fsid check' wrote check.rrd; run 'fsid check LOG --out {p}' again"
        )
    raise FsidError(
        f"no recording in '{p}' (no {p / 'run.rrd'} or check.rrd); run 'fsid run SCENARIO --out {p}', "
        f"'fsid estimate LOG --out {p}' or 'fsid check LOG --out {p}' to write one, or give a .rrd file"
    )


def rerun_binary() -> str:
    """Path of the rerun CLI: the binary shipped with rerun-sdk, else ``rerun`` on PATH."""
    try:
        import rerun_cli

        exe = Path(rerun_cli.__file__).parent / ("rerun.exe" if os.name == "nt" else "rerun")
        if exe.is_file():
            return str(exe)
    except ImportError:
        pass
    exe = shutil.which("rerun")
    if exe is None:
        raise FsidError(
            "the rerun viewer is not installed; run 'make setup' (or "
            "'pip install rerun-sdk==0.41.*') in the project's environment"
        )
    return exe


def has_display(env: Mapping[str, str] | None = None) -> bool:
    """True when a graphical session is available (X11 DISPLAY or WAYLAND_DISPLAY set)."""
    env = os.environ if env is None else env
    return bool(env.get("DISPLAY") or env.get("WAYLAND_DISPLAY"))


def free_port(bind: str = "127.0.0.1") -> int:
    """A TCP port that is free right now on ``bind``."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((bind, 0))
        return int(s.getsockname()[1])


def web_url(web_port: int, grpc_port: int, host: str = "127.0.0.1") -> str:
    """Address of the served web viewer, pointing it at the gRPC proxy holding the file."""
    proxy = f"rerun+http://{host}:{grpc_port}/proxy"
    return f"http://{host}:{web_port}/?url={quote(proxy, safe='')}"


def command(rrd: Path, *, web: bool, bind: str = "127.0.0.1", web_port: int = 9090, grpc_port: int = 9876) -> list[str]:
    """argv of the rerun CLI: native viewer on the file, or serve it to the web viewer."""
    exe = rerun_binary()
    if not web:
        return [exe, str(rrd)]
    return [exe, str(rrd), "--serve-web", "--bind", bind, "--web-viewer-port", str(web_port), "--port", str(grpc_port)]


def _terminate(signum: int, frame: object) -> None:
    """SIGTERM (a service manager, ``kill``) stops the viewer as Ctrl-C does: the rerun
    server is ended with it and its ports are freed."""
    raise KeyboardInterrupt


def sigint_stops() -> None:
    """Let Ctrl-C (SIGINT) reach this process even when whatever started it left SIGINT
    ignored (a background job of a script) or blocked (a test runner's worker thread):
    both are inherited across exec, and the viewer would then never stop. SIGTERM ends it
    the same way. Its rerun child inherits the restored state."""
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, _terminate)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})


def run(args: argparse.Namespace) -> int:
    sigint_stops()
    rrd = rrd_path(args.run_dir)
    web = bool(args.web) or not has_display()
    web_port = args.web_port or free_port(args.bind)
    grpc_port = args.grpc_port or free_port(args.bind)
    argv = command(rrd, web=web, bind=args.bind, web_port=web_port, grpc_port=grpc_port)
    if web:
        host = "127.0.0.1" if args.bind in ("0.0.0.0", "::") else args.bind
        print(f"serving {rrd} to the web viewer at {web_url(web_port, grpc_port, host)}", flush=True)
        print("open that address in a browser; Ctrl-C stops the server", flush=True)
    else:
        print(f"opening {rrd} in the rerun viewer", flush=True)
    try:
        proc = subprocess.Popen(argv)
    except OSError as exc:
        raise FsidError(
            f"could not start the rerun viewer '{argv[0]}': {exc}; reinstall rerun-sdk ('make setup')"
        ) from None
    try:
        rc = proc.wait()
    except KeyboardInterrupt:
        proc.terminate()
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
        print("viewer stopped", file=sys.stderr)
        return 0
    if rc != 0:
        raise FsidError(
            f"the rerun viewer exited with status {rc} on '{rrd}'"
            + (
                "; the ports may be taken: try --web-port 0 --grpc-port 0"
                if web
                else "; try 'fsid view --web' to use the web viewer"
            ),
            exit_code=1,
        )
    return 0
