"""`brainshift serve` under load, on loopback and bounded in count and time: the server as its
own process; one client makes --updates updates one after another (a point list, then the
STRING `update`, each waited for), while a second client floods 10,000 messages in a second
(STRING `update`, TRANSFORM tips, point lists, every tenth with a wrong CRC). Measured: the
first client's latency with and without the flood, the updates the flood cost, the server's
resident memory before and after (no growth beyond a fixed bound), and that every answer came.

    python benchmarks/serve_load.py --atlas ATLAS [--updates 10000]

Results: benchmarks/results/serve_load.md.
"""

from __future__ import annotations

import argparse
import json
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fenics_brainshift.atlas import store  # noqa: E402
from fenics_brainshift.bench import machine_line  # noqa: E402
from fenics_brainshift.theatre import igtl  # noqa: E402

BRAINSHIFT = str(Path(sys.executable).with_name("brainshift"))
FLOOD = 10_000
GROWTH_MB = 50.0  # the bound on the resident memory's growth over the run


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


class Client:
    def __init__(self, port: int):
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=20)
        self.buffer = b""

    def _take(self, size: int) -> bytes:
        while len(self.buffer) < size:
            data = self.sock.recv(1 << 20)
            if not data:
                raise ConnectionError("closed by the server")
            self.buffer += data
        out, self.buffer = self.buffer[:size], self.buffer[size:]
        return out

    def status(self) -> dict:
        """Read messages up to the next BrainshiftStatus; its JSON."""
        while True:
            head = self._take(igtl.HEADER_SIZE)
            _, kind, device, _, _, size, _ = struct.unpack(">H12s20sIIQQ", head)
            body = self._take(size)
            if device.rstrip(b"\0") == b"BrainshiftStatus":
                header = igtl.Header(2, "STRING", "BrainshiftStatus", 0.0, size, igtl.CRC64(body))
                return json.loads(igtl.decode(header, body).content)


def flood(port: int, points_mm: np.ndarray, done: dict) -> None:
    """10,000 messages in about a second on a second connection; its answers read and dropped."""
    sock = socket.create_connection(("127.0.0.1", port), timeout=60)
    labels = [f"f{i}" for i in range(len(points_mm))]
    kinds = [
        igtl.encode_string("cmd", "update"),
        igtl.encode_transform("Tip", np.eye(4)),
        igtl.encode_point("Touches", labels, points_mm),
    ]
    bad = bytearray(kinds[0])
    bad[-1] ^= 0xFF
    reader = threading.Thread(target=lambda: _drain(sock), daemon=True)
    reader.start()
    started = time.perf_counter()
    for k in range(FLOOD):
        sock.sendall(bytes(bad) if k % 10 == 9 else kinds[k % 3])
        if k % 1000 == 999:
            time.sleep(max(0.0, started + (k + 1) / FLOOD - time.perf_counter()))
    done["seconds"] = time.perf_counter() - started
    time.sleep(2.0)
    sock.close()


def _drain(sock) -> None:
    try:
        while sock.recv(1 << 20):
            pass
    except OSError:
        pass


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--atlas", required=True)
    parser.add_argument("--updates", type=int, default=10_000)
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "serve_load"))
    parser.add_argument("--built-by", default="", help="the command that built ATLAS, for the results file")
    args = parser.parse_args()
    atlas = store.read(args.atlas)
    top = np.flatnonzero(atlas.surface_points[:, 1] > np.percentile(atlas.surface_points[:, 1], 90))[:12]
    points_mm = (atlas.surface_points[top] + atlas.prior_surface[top]) * 1e3
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    log_file = tempfile.NamedTemporaryFile("w", suffix=".log", delete=False)  # noqa: SIM115 (the server's lines)
    server = subprocess.Popen(
        [BRAINSHIFT, "serve", args.atlas, "--port", str(port)], stdout=log_file, stderr=subprocess.STDOUT
    )
    try:
        while True:
            try:
                client = Client(port)
                break
            except OSError:
                time.sleep(0.02)
        client.sock.sendall(igtl.encode_point("Touches", [f"p{i}" for i in range(12)], points_mm))
        client.status()
        rss = [rss_mb(server.pid)]
        quiet, loaded, answered = [], [], 0
        flood_at = args.updates // 2
        flooding = {}
        for k in range(args.updates):
            if k == flood_at:
                threading.Thread(target=flood, args=(port, points_mm, flooding), daemon=True).start()
            t = time.perf_counter()
            client.sock.sendall(igtl.encode_string("cmd", "update"))
            status = client.status()
            answered += status.get("points") == 12
            (loaded if flood_at <= k < flood_at + 200 else quiet).append((time.perf_counter() - t) * 1e3)
            if k % 1000 == 999:
                rss.append(rss_mb(server.pid))
        rss.append(rss_mb(server.pid))
    finally:
        server.terminate()
        server.wait(20)
        log_file.close()
        log = Path(log_file.name).read_text(errors="replace")
        Path(log_file.name).unlink()
    p = lambda x, q: float(np.percentile(x, q))  # noqa: E731
    dropped = log.count("fails its CRC-64 check")
    suppressed = sum(int(line.split(": ")[1].split()[0]) for line in log.splitlines() if "more such lines" in line)
    growth = max(rss) - rss[1] if len(rss) > 1 else float("nan")
    lines = [
        "# `brainshift serve` under load",
        "",
        f"{machine_line()}; `python benchmarks/serve_load.py --atlas ATLAS --updates {args.updates}`; ATLAS: "
        f"`{args.built_by or 'brainshift atlas ...'}` ({atlas.info['modes']} modes, {atlas.info['nodes']} nodes). "
        f"One client updates {args.updates} times one "
        f"after another (12 points, the STRING `update`, the answer waited for); from its {flood_at}th update a "
        f"second client sends {FLOOD} messages (`update` strings, tips, point lists; every tenth with a wrong "
        f"CRC) in {flooding.get('seconds', float('nan')):.2f} s.",
        "",
        "| measure | value |",
        "|---|---|",
        f"| answers received / updates asked | {answered} / {args.updates} |",
        f"| latency without the flood: p50 / p99 / max | {p(quiet, 50):.1f} / {p(quiet, 99):.1f} / "
        f"{max(quiet):.1f} ms |",
        f"| latency in the 200 updates from the flood's start: p50 / p99 / max | {p(loaded, 50):.1f} / "
        f"{p(loaded, 99):.1f} / {max(loaded):.1f} ms |",
        f"| the flood's log: lines shown / lines held back (at most 20 a client per 10 s) | {dropped} / "
        f"{suppressed} (of {FLOOD // 10} wrong CRCs and the rest) |",
        f"| server resident memory: after the first update / largest / at the end | {rss[1]:.0f} / {max(rss):.0f} / "
        f"{rss[-1]:.0f} MB (growth {growth:.1f} MB; bound {GROWTH_MB:g} MB: "
        f"{'within' if growth <= GROWTH_MB else 'PAST IT'}) |",
    ]
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
