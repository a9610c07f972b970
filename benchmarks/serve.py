"""`brainshift serve` measured by a real client: the server started as its own process on
loopback, pyigtl's client connected as a navigation system would, playing the update
benchmark's synthetic operations (benchmarks/update.py: the full model solved with another
level, pose, material, swelling or stiffness than any mode): 20 cortex points arriving one by
one, an update after each (from the fifth), while a tracked tip streams at 60 Hz.

Measured, into benchmarks/results/serve.{md,csv}:
- the latency from sending a point list to receiving the update's last message (its status),
  p50 / p99 over every update; the server's own time for each (the status's update_ms);
- the same update through `brainshift update` as a process, in the same run: the baseline;
- the server's start-up with the atlas on disk (spawn to the port answering, median of 3);
- that the 60 Hz tip stream costs no update and grows no queue (updates = point lists sent);
- points to reach a target error when each touch follows the service's suggestion (NextPoint)
  against touching the exposed cortex at random, at five deep targets under the craniotomy
  (a tumour's place), mean over the operations (in process: theatre.case.Case).

    python benchmarks/serve.py --atlas ATLAS [--repeats 2]

ATLAS: `brainshift atlas brain --set mesh.voxel=0.005 --set time.mode=quasi-static --set
skull.gap=0.003 -o ATLAS` (its --set are read back from atlas.json for the operations).
"""

from __future__ import annotations

import argparse
import csv
import importlib.util
import json
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
os.environ.setdefault("OMP_NUM_THREADS", "1")

import pyigtl  # noqa: E402

from fenics_brainshift import logs  # noqa: E402
from fenics_brainshift.atlas import store  # noqa: E402
from fenics_brainshift.atlas.locate import MeshLocator  # noqa: E402
from fenics_brainshift.bench import machine_line  # noqa: E402
from fenics_brainshift.images import write_markups  # noqa: E402
from fenics_brainshift.theatre.case import Case  # noqa: E402

POINTS, FIRST, NOISE = 20, 5, 0.5e-3  # cortex points an operation, the first update's, their noise (m)
TIP_HZ = 60.0
TARGET_DEPTH = 25e-3  # m under the exposed cortex: the deep targets
THRESHOLDS_MM = (1.0, 0.5, 0.3)
RANDOM_SEEDS = 5
PARTS = ("cross_validation_ms", "fit_ms", "leave_one_out_and_spread_ms", "total_ms")  # of the update's fit
BRAINSHIFT = str(Path(sys.executable).with_name("brainshift"))


def _update_benchmark():
    spec = importlib.util.spec_from_file_location("update_benchmark", ROOT / "benchmarks" / "update.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def operations(atlas, base: list[str]):
    """(name, the true displacement at the nodes and at the fine surface) per operation."""
    bench = _update_benchmark()
    folder = Path(tempfile.mkdtemp(prefix="brainshift-serve-bench-"))
    index, weight, _ = MeshLocator(atlas.points, atlas.tetrahedra).weights(atlas.surface_points)
    out = []
    for name, (overrides, values, extra) in bench.OPERATIONS.items():
        points, u, _ = bench.truth_state(base, overrides, values, extra, folder)
        assert np.abs(points - atlas.points).max() < 1e-9
        out.append((name, u, np.einsum("nj,njd->nd", weight, u[index])))
        print(f"truth: {name}", flush=True)
    return out


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_server(atlas: str, port: int) -> tuple[subprocess.Popen, float]:
    """The server as its own process; seconds from spawn until its port answers."""
    started = time.perf_counter()
    process = subprocess.Popen(
        [BRAINSHIFT, "serve", atlas, "--port", str(port)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    while True:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.05).close()
            return process, time.perf_counter() - started
        except OSError:
            if process.poll() is not None:
                raise RuntimeError(f"the server stopped: {process.stdout.read()}") from None
            time.sleep(0.005)


class Tip(threading.Thread):
    """A tracked pointer's tip at 60 Hz on a circle above the cortex (never at rest)."""

    def __init__(self, client, centre_mm: np.ndarray):
        super().__init__(daemon=True)
        self.client, self.centre, self.stop, self.sent = client, centre_mm, threading.Event(), 0

    def run(self):
        t0 = time.perf_counter()
        while not self.stop.is_set():
            t = time.perf_counter() - t0
            matrix = np.eye(4)
            matrix[:3, 3] = self.centre + 20.0 * np.array([np.cos(t), 0.0, np.sin(t)]) + [0.0, 30.0, 0.0]
            self.client.send_message(pyigtl.TransformMessage(matrix, device_name="PointerToTracker"), wait=False)
            self.sent += 1
            time.sleep(max(0.0, t0 + self.sent / TIP_HZ - time.perf_counter()))


def wait_status(client, points: int, timeout: float = 30.0) -> dict:
    """The status answering a list of this many points (pyigtl keeps a device's latest)."""
    deadline = time.perf_counter() + timeout
    while time.perf_counter() < deadline:
        message = client.wait_for_message("BrainshiftStatus", timeout=0.001)
        if message is not None:
            status = json.loads(message.string)
            if status.get("points") == points or "error" in status:
                return status
    raise TimeoutError(f"no status for {points} points in {timeout} s")


def exposed(atlas) -> np.ndarray:
    """The fine surface's vertices of the exposed cortex (as benchmarks/update.py: y > 30 mm)."""
    return np.flatnonzero(atlas.surface_points[:, 1] > 0.03)


def latency(atlas_folder: str, atlas, ops, repeats: int, port: int) -> tuple[list[dict], dict]:
    process, _ = start_server(atlas_folder, port)
    client = pyigtl.OpenIGTLinkClient("127.0.0.1", port)
    tip = Tip(client, atlas.surface_points[exposed(atlas)].mean(axis=0) * 1e3)
    rows, sent = [], 0
    try:
        time.sleep(0.5)
        tip.start()
        for repeat in range(repeats):
            for k, (name, _, truth_surface) in enumerate(ops):
                rng = np.random.default_rng(100 * repeat + k)
                picked = rng.choice(exposed(atlas), POINTS, replace=False)
                measured = atlas.surface_points[picked] + truth_surface[picked] + rng.normal(0.0, NOISE, (POINTS, 3))
                for n in range(FIRST, POINTS + 1):
                    message = pyigtl.PointMessage(
                        positions=measured[:n] * 1e3, names=[f"p{i}" for i in range(n)], device_name="Touches"
                    )
                    t = time.perf_counter()
                    client.send_message(message, wait=False)
                    status = wait_status(client, n)
                    rows.append(
                        {
                            "operation": name,
                            "repeat": repeat,
                            "points": n,
                            "latency_ms": (time.perf_counter() - t) * 1e3,
                            "server_update_ms": status.get("update_ms", float("nan")),
                            **{k: status.get("timings_ms", {}).get(k, float("nan")) for k in PARTS},
                            "error": status.get("error", ""),
                        }
                    )
                    sent += 1
        client.send_message(pyigtl.StringMessage("status", device_name="cmd"), wait=False)
        time.sleep(0.5)
        message = client.wait_for_message("BrainshiftStatus", timeout=5)
        updates = json.loads(message.string).get("updates") if message else None
    finally:
        tip.stop.set()
        tip.join(2)
        client.stop()
        process.terminate()
        process.wait(10)
    return rows, {"point_lists": sent, "updates": updates, "tip_messages": tip.sent}


def baseline(atlas_folder: str, atlas, ops, folder: Path) -> tuple[float, float]:
    """`brainshift update` as a process on the same 20 points: (median wall s, its own total ms)."""
    _, _, truth_surface = ops[0]
    rng = np.random.default_rng(0)
    picked = rng.choice(exposed(atlas), POINTS, replace=False)
    measured = atlas.surface_points[picked] + truth_surface[picked] + rng.normal(0.0, NOISE, (POINTS, 3))
    write_markups(folder / "touches.mrk.json", [f"p{i}" for i in range(POINTS)], measured * 1e3)
    walls, totals = [], []
    for k in range(3):
        t = time.perf_counter()
        subprocess.run(
            [BRAINSHIFT, "update", atlas_folder, "--target", str(folder / "touches.mrk.json"), "--out",
             str(folder / f"u{k}"), "--noise", str(NOISE * 1e3)],
            check=True, capture_output=True,
        )  # fmt: skip
        walls.append(time.perf_counter() - t)
        totals.append(json.loads((folder / f"u{k}" / "update.json").read_text())["timings_ms"]["total_ms"])
    return float(np.median(walls)), float(np.median(totals))


def deep_targets(atlas) -> np.ndarray:
    """Five nodes TARGET_DEPTH under the exposed cortex's centre (against gravity), a tumour's place."""
    top = atlas.surface_points[exposed(atlas)].mean(axis=0)
    centre = top - np.array([0.0, TARGET_DEPTH, 0.0])
    near = np.argsort(np.linalg.norm(atlas.points - centre, axis=1))[:5]
    return atlas.points[near]


def suggestions_against_random(atlas, ops) -> list[dict]:
    """Error at the deep targets after each touch, following NextPoint or at random."""
    targets = deep_targets(atlas)
    index, weight, _ = MeshLocator(atlas.points, atlas.tetrahedra).weights(targets)
    base = Case(atlas, targets=([f"t{i}" for i in range(5)], targets), noise=NOISE, grid=None)
    candidates = exposed(atlas)
    rows = []
    for name, truth, truth_surface in ops:
        true_at = np.einsum("nj,njd->nd", weight, truth[index])
        for way in ["suggested"] + [f"random{s}" for s in range(RANDOM_SEEDS)]:
            rng = np.random.default_rng(7 if way == "suggested" else 1000 + int(way[6:]))
            case = base.fresh()
            touched = list(rng.choice(candidates, FIRST, replace=False))
            for n in range(FIRST, POINTS + 1):
                positions = atlas.surface_points[touched] + truth_surface[touched]
                positions = positions + np.random.default_rng(n).normal(0.0, NOISE, positions.shape)
                case.set_points([f"p{i}" for i in range(len(touched))], positions)
                answer = case.update()
                moved = np.einsum("nj,njd->nd", weight, answer.result.displacement[index])
                rows.append(
                    {
                        "operation": name,
                        "way": "suggested" if way == "suggested" else "random",
                        "seed": way,
                        "points": n,
                        "target_error_mm": float(np.linalg.norm(moved - true_at, axis=1).mean() * 1e3),
                        "target_spread_mm": answer.suggestion.spread * 1e3 if answer.suggestion else float("nan"),
                    }
                )
                if way == "suggested" and answer.suggestion is not None:
                    touched.append(answer.suggestion.vertex)
                else:
                    touched.append(int(rng.choice(np.setdiff1d(candidates, touched))))
        print(f"suggestions: {name}", flush=True)
    return rows


def points_to_reach(rows: list[dict], way: str, threshold: float) -> float:
    """Mean over operations (and random seeds) of the first point count whose error stays below
    the threshold from there on (POINTS + 1 if never)."""
    counts = []
    for key in sorted({(r["operation"], r["seed"]) for r in rows if r["way"] == way}):
        curve = sorted((r["points"], r["target_error_mm"]) for r in rows if (r["operation"], r["seed"]) == key)
        reached = POINTS + 1
        for n, _ in curve:
            if all(e < threshold for m, e in curve if m >= n):
                reached = n
                break
        counts.append(reached)
    return float(np.mean(counts))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--atlas", required=True)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "serve"))
    args = parser.parse_args()
    logs.configure("WARNING")
    atlas = store.read(args.atlas)
    started = time.perf_counter()  # the start-up's parts, in this process (the service's own order)
    from fenics_brainshift.atlas.prepared import locator, moving_surface, prior_weights, skull_at_prior

    parts = {"read the atlas": store.read(args.atlas)}
    loaded = parts["read the atlas"]
    parts["read the atlas"] = time.perf_counter() - started
    for name, step in (
        ("prior weights, locator, surface", lambda: (prior_weights(loaded), locator(loaded), moving_surface(loaded))),
        ("the skull's rows at the prior", lambda: skull_at_prior(loaded)),
        ("the grid and the exposed cortex", lambda: Case(loaded)),
    ):
        t = time.perf_counter()
        step()
        parts[name] = time.perf_counter() - t
    startups = []  # (first: spawned from a parent holding DOLFINx and MPI, each start took longer)
    for _ in range(3):
        process, seconds = start_server(args.atlas, free_port())
        process.terminate()
        process.wait(10)
        startups.append(seconds)
    base = list(atlas.info.get("set") or []) + ["time.mode=quasi-static"]
    ops = operations(atlas, base)
    rows, stream = latency(args.atlas, atlas, ops, args.repeats, free_port())
    with tempfile.TemporaryDirectory() as tmp:
        wall_s, command_total_ms = baseline(args.atlas, atlas, ops, Path(tmp))
    walk = suggestions_against_random(atlas, ops)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out.with_suffix(".csv"), "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    with open(out.with_name(out.name + "_suggestions.csv"), "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(walk[0]))
        writer.writeheader()
        writer.writerows(walk)
    latencies = np.array([r["latency_ms"] for r in rows])
    fit_total = np.array([r["total_ms"] for r in rows])
    server_ms = np.array([r["server_update_ms"] for r in rows])
    at_20 = np.array([r["latency_ms"] for r in rows if r["points"] == POINTS])
    errors = [r for r in rows if r["error"]]
    p = lambda x, q: float(np.percentile(x, q))  # noqa: E731
    mean_curve = {
        way: [float(np.mean([r["target_error_mm"] for r in walk if r["way"] == way and r["points"] == n]))
              for n in range(FIRST, POINTS + 1)]
        for way in ("suggested", "random")
    }  # fmt: skip
    info = atlas.info
    lines = [
        "# `brainshift serve`: latency measured by a real client, against `brainshift update` as a process",
        "",
        f"{machine_line()}; `python benchmarks/serve.py --atlas ATLAS --repeats {args.repeats}`; ATLAS: `brainshift "
        f"atlas brain {' '.join('--set ' + s for s in info.get('set', []))} -o ATLAS` ({info['modes']} modes, "
        f"{info['nodes']} nodes, fine surface {len(atlas.surface_points)} vertices). The server is its own process "
        "on loopback; the client is pyigtl's OpenIGTLinkClient (its thread polls its socket every 10 ms), with a "
        f"tracked tip's TRANSFORM at {TIP_HZ:g} Hz on the same connection throughout. Each operation: {POINTS} "
        f"points of the true moved cortex ({NOISE * 1e3:g} mm noise) sent as a growing POINT list, an update from "
        f"the {FIRST}th.",
        "",
        "| measure | value |",
        "|---|---|",
        f"| updates measured | {len(rows)} ({len(errors)} answered with an error) |",
        f"| latency, send to the status received: p50 / p99 / max | **{p(latencies, 50):.0f} / {p(latencies, 99):.0f}**"
        f" / {latencies.max():.0f} ms |",
        f"| ... with 20 points: p50 / p99 | {p(at_20, 50):.0f} / {p(at_20, 99):.0f} ms |",
        f"| the server's update (status update_ms): p50 / p99 | {p(server_ms, 50):.0f} / {p(server_ms, 99):.0f} ms |",
        f"| `brainshift update` as a process, 20 points: wall (median of 3) / its own update | {wall_s * 1e3:.0f} ms "
        f"/ {command_total_ms:.0f} ms |",
        f"| server start-up with the atlas on disk (spawn to the port answering, median of 3) | "
        f"{np.median(startups):.2f} s |",
        f"| tip stream: TRANSFORM messages sent / point lists sent / updates made | {stream['tip_messages']} / "
        f"{stream['point_lists']} / {stream['updates']} |",
        "",
        "Where the time goes, p50 / p99 over the same updates (ms): the fit's parts as the update times them "
        "(cross-validation of alpha, the rounds of nearest points and skull rows, leave-one-out and the spread), "
        "the answer's other parts on the server (the grid images, the suggestion, the moved surfaces), and the "
        "message's way (encoding, loopback, pyigtl's client):",
        "",
        "| cross-validation | rounds | leave-one-out and spread | the fit in all | the rest of the answer | the way |",
        "|---|---|---|---|---|---|",
        "| "
        + " | ".join(
            f"{p(x, 50):.0f} / {p(x, 99):.0f}"
            for x in (
                np.array([r["cross_validation_ms"] for r in rows]),
                np.array([r["fit_ms"] for r in rows]),
                np.array([r["leave_one_out_and_spread_ms"] for r in rows]),
                np.array([r["total_ms"] for r in rows]),
                server_ms - np.array([r["total_ms"] for r in rows]),
                latencies - server_ms,
            )
        )
        + " |",
        "",
        "What stands in the way of the goals (p99 at most 100 ms, start-up under 1 s): "
        + (
            f"p99 {p(latencies, 99):.0f} ms: the fit itself (p50/p99 {p(fit_total, 50):.0f}/{p(fit_total, 99):.0f} "
            f"ms), mostly its rounds and, when alpha is chosen again, the cross-validation; "
            if p(latencies, 99) > 100
            else f"p99 {p(latencies, 99):.0f} ms: met; "
        )
        + f"start-up {np.median(startups):.2f} s"
        + (" (met)" if np.median(startups) < 1 else "")
        + ", of which in process: "
        + ", ".join(f"{name} {seconds:.2f} s" for name, seconds in parts.items())
        + " (and Python's imports).",
        "",
        f"## Suggested touches against random ones ({len(ops)} operations, error at 5 deep targets "
        f"{TARGET_DEPTH * 1e3:g} mm under the exposed cortex; random: mean of {RANDOM_SEEDS} seeds)",
        "",
        "| points | " + " | ".join(str(n) for n in range(FIRST, POINTS + 1, 3)) + " |",
        "|---|" + "---|" * len(range(FIRST, POINTS + 1, 3)),
    ]
    for way in ("suggested", "random"):
        lines.append(
            f"| {way} (mm) | "
            + " | ".join(f"{mean_curve[way][n - FIRST]:.2f}" for n in range(FIRST, POINTS + 1, 3))
            + " |"
        )
    lines += [
        "",
        "| points to stay below | " + " | ".join(f"{t:g} mm" for t in THRESHOLDS_MM) + " |",
        "|---|" + "---|" * len(THRESHOLDS_MM),
    ]
    for way in ("suggested", "random"):
        lines.append(f"| {way} | " + " | ".join(f"{points_to_reach(walk, way, t):.1f}" for t in THRESHOLDS_MM) + " |")
    lines += [
        "",
        f"points to stay below: the first count from which the targets' mean error stays below the threshold "
        f"({POINTS + 1} if never), mean over the operations. Per update: {out.with_suffix('.csv').name}; per touch: "
        f"{out.name}_suggestions.csv.",
    ]
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
