# ---
# jupyter:
#   jupytext:
#     formats: py:light
# ---

# # In theatre, live: a synthetic operation played against `brainshift serve`
#
# The service runs as its own process on loopback, holding an atlas of the bundled brain; a
# navigation system's part is played here with pyigtl's client. The "true" operation is made
# by the full model on its own (demos/update.py's: the CSF drained to 35 mm, G = 3000 Pa, the
# head turned between the atlas's poses). A pointer touches the exposed cortex, one point at a
# time; after each touch the service answers with the updated brain and the next point worth
# touching (NextPoint). Played twice: following the suggestions, and touching at random. The
# error at five deep targets (a tumour's place, 25 mm under the exposed cortex), read from the
# moved targets the service sends, against the number of points.
#
#     python demos/live.py                              # 10 mm brain: builds its atlas first
#     python demos/live.py --atlas ATLAS --set ...      # an atlas built with the same --set
#
# out_live/: atlas/ (unless --atlas), targets.mrk.json, live.json (both curves), live.png.

# +
import argparse
import json
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyigtl
from mpi4py import MPI

from fenics_brainshift import InputError, SolverError, logs
from fenics_brainshift.atlas import store
from fenics_brainshift.atlas.locate import MeshLocator
from fenics_brainshift.cli import main as brainshift
from fenics_brainshift.fit.synthetic import true_scene
from fenics_brainshift.images import write_markups
from fenics_brainshift.outputs.vertices import GlobalVertices
from fenics_brainshift.runner import Simulation

TRUTH = {"fluid.level": 0.035, "material.G": 3000.0, "gravity.angle_z": 8.0, "gravity.angle_x": -4.0}
NOISE_MM = 0.5
FIRST = 5  # touches before the first update (a fit to the surface needs five)
DEPTH_MM = 25.0
BRAINSHIFT = str(Path(sys.executable).with_name("brainshift"))
# -


def parse_args(argv=None):
    p = argparse.ArgumentParser(
        description="Play a synthetic operation against brainshift serve: suggested and random touches.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--out", default="out_live", help="output folder")
    p.add_argument("--atlas", help="an atlas of the bundled brain built with the same --set (default: build one)")
    p.add_argument("--set", action="append", default=None, metavar="SECTION.KEY=VALUE", help="scene overrides")
    p.add_argument("--touches", type=int, default=20, help="points touched in each play")
    p.add_argument("--seed", type=int, default=1, help="of the first touches and the noise")
    return p.parse_args(argv)


# ## Before surgery: the atlas, the targets, the truth; in theatre: the service


# +
def main(argv=None) -> int:
    args = parse_args(argv)
    args.set = args.set if args.set is not None else ["mesh.voxel=0.01"]
    logs.configure("WARNING")
    if MPI.COMM_WORLD.size > 1:
        print("live.py: one process (the service is one)", file=sys.stderr)
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    try:
        folder = Path(args.atlas) if args.atlas else out / "atlas"
        if not args.atlas:
            sets = [a for s in args.set for a in ("--set", s)]
            code = brainshift(["--log-level", "WARNING", "atlas", "brain", "-o", str(folder), *sets])
            if code:
                return code
        atlas = store.read(folder)
        truth = true_state(args.set)
    except (InputError, SolverError) as exc:
        print(f"live.py: error: {exc}", file=sys.stderr)
        return 2 if isinstance(exc, InputError) else 3
    index, weight, _ = MeshLocator(atlas.points, atlas.tetrahedra).weights(atlas.surface_points)
    truth_surface = np.einsum("nj,njd->nd", weight, truth[index])
    exposed = np.flatnonzero(atlas.surface_points[:, 1] > 0.03)
    targets = deep_targets(atlas, exposed)
    write_markups(out / "targets.mrk.json", [f"T{i + 1}" for i in range(len(targets))], targets * 1e3)
    index, weight, _ = MeshLocator(atlas.points, atlas.tetrahedra).weights(targets)
    true_targets = targets + np.einsum("nj,njd->nd", weight, truth[index])
    port = free_port()
    server = subprocess.Popen(
        [BRAINSHIFT, "serve", str(folder), "--port", str(port), "--targets", str(out / "targets.mrk.json"),
         "--noise", str(NOISE_MM)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    try:
        wait_for(port, server)
        curves = {
            way: play(port, atlas, truth_surface, exposed, true_targets, way, args.touches, args.seed)
            for way in ("suggested", "random")
        }
    finally:
        server.terminate()
        server.wait(10)
    (out / "live.json").write_text(json.dumps({"noise_mm": NOISE_MM, "first": FIRST, **curves}, indent=2))
    for way, curve in curves.items():
        print(f"{way:10s} target error (mm) after {FIRST}..{args.touches} touches: " + " ".join(
            f"{e:.2f}" for e in curve["target_error_mm"]))  # fmt: skip
    picture(out, curves)
    print(f"  wrote {out}/live.png")
    return 0


def true_state(overrides) -> np.ndarray:
    """The true operation's displacement at the atlas's vertices (the full model, on its own)."""
    scene = true_scene(overrides, TRUTH)
    sim = Simulation(scene, MPI.COMM_WORLD)
    sim.setup()
    sim.solve_to_settled(scene.time.end)
    u = GlobalVertices(sim.model.mesh).values(sim.u)
    sim.destroy()
    return u


def deep_targets(atlas, exposed) -> np.ndarray:
    """Five nodes DEPTH_MM under the exposed cortex's centre (the brain lies supine: y up)."""
    centre = atlas.surface_points[exposed].mean(axis=0) - [0.0, DEPTH_MM * 1e-3, 0.0]
    return atlas.points[np.argsort(np.linalg.norm(atlas.points - centre, axis=1))[:5]]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_for(port: int, server: subprocess.Popen) -> None:
    while True:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.1).close()
            return
        except OSError:
            if server.poll() is not None:
                raise RuntimeError(f"brainshift serve stopped: {server.stdout.read()}") from None
            time.sleep(0.05)


# -


# ## The navigation system's part: touch, send, read the answer


# +
def play(port, atlas, truth_surface, exposed, true_targets, way, touches, seed) -> dict:
    """Touch the true cortex (0.5 mm noise) at FIRST random points, then at the service's
    NextPoint (the surface vertex nearest it) or at random; the target error after each."""
    rng = np.random.default_rng(seed)
    noise = np.random.default_rng(seed + 1).normal(0.0, NOISE_MM, (touches, 3))
    at_prior = atlas.surface_points + atlas.prior_surface
    touched = list(rng.choice(exposed, FIRST, replace=False))
    errors, spreads, latencies = [], [], []
    client = pyigtl.OpenIGTLinkClient("127.0.0.1", port)
    try:
        client.send_message(pyigtl.StringMessage("reset", device_name="cmd"))
        _status(client, lambda s: "reset" in s)
        while len(touched) <= touches:
            n = len(touched)
            positions = (atlas.surface_points[touched] + truth_surface[touched]) * 1e3 + noise[: len(touched)]
            t = time.perf_counter()
            client.send_message(pyigtl.PointMessage(positions=positions, names=[f"p{i}" for i in range(n)],
                                                    device_name="Touches"))  # fmt: skip
            status = _status(client, lambda s, n=n: s.get("points") == n)
            latencies.append((time.perf_counter() - t) * 1e3)
            moved = np.asarray(client.wait_for_message("BrainshiftTargets", timeout=5).positions) * 1e-3
            errors.append(float(np.linalg.norm(moved - true_targets, axis=1).mean() * 1e3))
            spreads.append(status["targets_spread_mm"])
            if len(touched) == touches:
                break
            if way == "suggested":
                suggested = np.asarray(client.wait_for_message("NextPoint", timeout=5).positions)[0] * 1e-3
                touched.append(int(exposed[np.argmin(np.linalg.norm(at_prior[exposed] - suggested, axis=1))]))
            else:
                touched.append(int(rng.choice(np.setdiff1d(exposed, touched))))
    finally:
        client.stop()
    return {"target_error_mm": errors, "targets_spread_mm": spreads, "latency_ms": latencies}


def _status(client, wanted, timeout: float = 60.0) -> dict:
    deadline = time.perf_counter() + timeout
    while time.perf_counter() < deadline:
        message = client.wait_for_message("BrainshiftStatus", timeout=0.01)
        if message is not None:
            status = json.loads(message.string)
            if "error" in status:
                raise RuntimeError(f"the service said: {status['error']}")
            if wanted(status):
                return status
    raise TimeoutError("no answer from the service")


# -


# ## The error at the targets against the number of touches


# +
def picture(out: Path, curves: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for way, style in (("suggested", "o-"), ("random", "s--")):
        e = curves[way]["target_error_mm"]
        n = np.arange(FIRST, FIRST + len(e))
        ax.plot(n, e, style, label=f"{way}: error at the targets")
        ax.plot(n, curves[way]["targets_spread_mm"], style[0] + ":", alpha=0.6, label=f"{way}: the spread said")
    ax.set_xlabel("points touched")
    ax.set_ylabel("mean error at 5 deep targets (mm)")
    ax.set_title(
        f"brainshift serve: touches following NextPoint against random ones ({NOISE_MM} mm noise)", fontsize=10
    )
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "live.png", dpi=90)
    plt.close(fig)


# -

if __name__ == "__main__":
    sys.exit(main())
