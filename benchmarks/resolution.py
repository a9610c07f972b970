"""The skull atlas at clinical resolution: what one pose's chain of levels costs at 5, 3 and
2 mm voxels, on one rank and as one group of two (--ranks-per-mode 2), with the peak memory
of each command and the atlas's size on disk; from those, the default atlas's wall time on 1,
2, 16 and 64 ranks, extrapolated.

Writes benchmarks/results/resolution.md and resolution.json.

    python benchmarks/resolution.py [--voxels 0.005,0.003,0.002] [--levels 14] [--keep]

--keep keeps the rows of resolution.json that this run does not measure (another voxel or
group size, measured by an earlier command: the file names each row's command); --report
writes resolution.md again from resolution.json.

    python benchmarks/resolution.py --whole 2 --voxels 0.003 [--keep] [--keep-atlas DIR]

measures the whole default atlas instead (no --vary: 25 poses x 14 levels and the swelling
mode) under `mpirun -n 2` (one group of one rank each), beside the extrapolation; --keep-atlas
keeps the atlas it builds (for `python benchmarks/update.py --atlas DIR`).

Each build is its own process (`mpirun -n 2` for the group of two), after one unmeasured build
at 10 mm for the JIT cache. Measured: `brainshift atlas brain --set mesh.voxel=V
--set skull.gap=0.003 --vary fluid.level=-0.015:0.05:L` (one pose: the scene's; L levels, a
chain of warm starts, and the swelling mode), the wall time of the command, atlas.json's setup
and mode seconds, and the largest resident memory of any of its processes (getrusage of the
children, a fresh wrapper process per command).

The extrapolation: the default atlas is 25 poses x 14 levels and one swelling mode (atlas/
scenarios.py), its poses dealt whole to the rank groups (atlas/groups.py). With R ranks in
groups of r, a group solves ceil(25 / (R / r)) chains; the wall time is the setup (the mesh,
the factor: atlas.json's setup_s), the prior state from rest and the swelling mode (group 0's
prior_and_swelling_s), and that many chains of 14 levels at the measured cost of a family mode
in a chain (family_s / family_modes) for groups of that size. Groups of 1 are measured on one rank
(two groups of one on this machine cost what one rank costs: benchmarks/results/
atlas_ranks.md, 0.54 of one rank's wall time for two ranks); groups of 2 by --ranks-per-mode 2.
Not measured here: groups of more than two ranks, a network between machines (MPI talks only
within a group while it solves; the modes are gathered once at the end), and each machine's
file system (every rank reads the scene and its mesh).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fenics_brainshift.bench import machine_line  # noqa: E402

DEFAULT_POSES, DEFAULT_LEVELS = 25, 14  # atlas/scenarios.py: 14 levels x (5 x 5 angles)
RANKS = (1, 2, 16, 64)

# a fresh process per command: its children's largest resident set is that command's alone
MEASURE = """
import json, resource, subprocess, sys, time
start = time.perf_counter()
done = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
print(json.dumps({"seconds": time.perf_counter() - start, "returncode": done.returncode,
                  "peak_mb": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024,
                  "stderr": done.stderr[-2000:]}))
"""


def atlas_command(voxel: float, levels: int, out: Path, group: int) -> list[str]:
    launcher = ["mpirun", "-n", str(group)] if group > 1 else []
    extra = ["--ranks-per-mode", str(group)] if group > 1 else []
    return [
        *launcher, sys.executable, "-m", "fenics_brainshift.cli", "--no-progress", "atlas", "brain", "-o", str(out),
        "--set", f"mesh.voxel={voxel}", "--set", "skull.gap=0.003",
        "--vary", f"fluid.level=-0.015:0.05:{levels}", *extra,
    ]  # fmt: skip


def measure(command: list[str]) -> dict:
    env = dict(os.environ, OMP_NUM_THREADS="1", OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    out = subprocess.run([sys.executable, "-c", MEASURE, *command], capture_output=True, text=True, env=env, check=True)
    result = json.loads(out.stdout)
    if result["returncode"] != 0:
        sys.exit(f"{' '.join(command)} failed ({result['returncode']}):\n{result['stderr']}")
    return result


def build(voxel: float, levels: int, group: int, work: Path) -> dict:
    out = work / f"v{voxel}_g{group}"
    shutil.rmtree(out, ignore_errors=True)
    result = measure(atlas_command(voxel, levels, out, group))
    info = json.loads((out / "atlas.json").read_text())
    family = sum(1 for s in info["scenarios"] if s["kind"] == "family")
    row = {
        "voxel_mm": round(voxel * 1e3, 3),
        "group": group,
        "levels": levels,
        "nodes": info["nodes"],
        "cells": info["cells"],
        "modes": info["modes"],
        "family_modes": family,
        "wall_s": result["seconds"],
        "setup_s": info["setup_s"],
        "modes_s": info["modes_s"],
        "family_s": info["family_s"],
        "per_family_mode_s": info["family_s"] / info["family_modes"],
        "prior_and_swelling_s": info["prior_and_swelling_s"],
        "peak_mb": result["peak_mb"],
        "h5_mb": (out / "atlas.h5").stat().st_size / 2**20,
        "surface_points": surface_points(out / "atlas.h5"),
    }
    shutil.rmtree(out, ignore_errors=True)
    return row


def build_whole(voxel: float, ranks: int, work: Path, keep: Path | None) -> dict:
    """The default atlas at ``voxel`` on ``ranks`` ranks (groups of one), measured whole."""
    out = keep or work / f"whole_v{voxel}_r{ranks}"
    shutil.rmtree(out, ignore_errors=True)
    launcher = ["mpirun", "-n", str(ranks)] if ranks > 1 else []
    result = measure([
        *launcher, sys.executable, "-m", "fenics_brainshift.cli", "--no-progress", "atlas", "brain", "-o", str(out),
        "--set", f"mesh.voxel={voxel}", "--set", "skull.gap=0.003",
    ])  # fmt: skip
    info = json.loads((out / "atlas.json").read_text())
    row = {
        "whole": True,
        "voxel_mm": round(voxel * 1e3, 3),
        "ranks": ranks,
        "groups": info["ranks"] // info["ranks_per_mode"],
        "nodes": info["nodes"],
        "modes": info["modes"],
        "left_out": len(info.get("left_out", [])),
        "wall_s": result["seconds"],
        "setup_s": info["setup_s"],
        "modes_s": info["modes_s"],
        "peak_mb": result["peak_mb"],
        "h5_mb": (out / "atlas.h5").stat().st_size / 2**20,
        "columns": (info.get("contact_compliance") or {}).get("columns"),
    }
    if keep is None:
        shutil.rmtree(out, ignore_errors=True)
    return row


def surface_points(h5: Path) -> int:
    """How many points the atlas's fine surface has (0: none)."""
    import h5py

    with h5py.File(h5, "r") as f:
        return int(f["surface/points"].shape[0]) if "surface" in f else 0


def default_size_gb(row: dict, modes: int) -> float:
    """atlas.h5 with ``modes`` modes: the measured file less its own modes (the mesh, the prior,
    the fine surface, the skull: the same for any number of modes) plus ``modes`` modes in
    single precision at the nodes and the fine surface."""
    per_mode = (row["nodes"] + row["surface_points"]) * 3 * 4 / 2**20
    return (row["h5_mb"] + (modes - row["modes"]) * per_mode) / 1024


def extrapolate(one: dict, two: dict | None) -> dict[int, tuple[float, str]]:
    """The default atlas's wall time (s) on R ranks and how the ranks are grouped."""
    modes = DEFAULT_POSES * DEFAULT_LEVELS + 1
    out = {}
    for ranks in RANKS:
        options = [(1, one)] + ([(2, two)] if two and ranks % 2 == 0 else [])
        best = None
        for size, row in options:
            groups = ranks // size
            chains = math.ceil(DEFAULT_POSES / groups)
            wall = row["setup_s"] + row["prior_and_swelling_s"] + chains * DEFAULT_LEVELS * row["per_family_mode_s"]
            busy = min(groups, DEFAULT_POSES)  # (a pose is never split: more groups than poses wait)
            label = f"{busy} group{'s' if busy > 1 else ''} of {size}"
            label += f", {(groups - busy) * size} ranks idle" if groups > busy else ""
            if best is None or wall < best[0]:
                best = (wall, label)
        out[ranks] = best
    out["modes"] = modes
    return out


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--voxels", default="0.005,0.003,0.002", help="m, comma-separated")
    parser.add_argument("--levels", type=int, default=DEFAULT_LEVELS, help="levels of the measured chain")
    parser.add_argument("--groups", default="1,2", help="group sizes to measure (1: one rank; 2: mpirun -n 2)")
    parser.add_argument("--keep", action="store_true", help="keep resolution.json's rows this run does not measure")
    parser.add_argument("--report", action="store_true", help="write resolution.md from resolution.json, no builds")
    parser.add_argument("--whole", type=int, metavar="RANKS", help="measure the whole default atlas on RANKS ranks")
    parser.add_argument("--keep-atlas", type=Path, metavar="DIR", help="with --whole: keep the atlas it builds in DIR")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    args = parser.parse_args(argv)
    voxels = [float(v) for v in args.voxels.split(",")]
    groups = [int(g) for g in args.groups.split(",")]
    if args.report:
        write(json.loads((args.out / "resolution.json").read_text())["rows"], args.out)
        return
    if args.whole:
        command = f"python benchmarks/resolution.py --whole {args.whole} --voxels {args.voxels}"
        measured = {_key({"whole": True, "voxel_mm": round(v * 1e3, 3), "ranks": args.whole}) for v in voxels}
    else:
        command = (
            f"python benchmarks/resolution.py --voxels {args.voxels} --levels {args.levels} --groups {args.groups}"
        )
        measured = {_key({"voxel_mm": round(v * 1e3, 3), "group": g}) for v in voxels for g in groups}
    rows = []
    if args.keep and (args.out / "resolution.json").is_file():
        kept = json.loads((args.out / "resolution.json").read_text())["rows"]
        rows = [r for r in kept if _key(r) not in measured]
    with tempfile.TemporaryDirectory(prefix="resolution_") as tmp:
        work = Path(tmp)
        build(0.01, 2, 1, work)  # the JIT cache, unmeasured (the forms are the same at every voxel)
        if args.whole:
            for voxel in voxels:
                row = {**build_whole(voxel, args.whole, work, args.keep_atlas), "command": command}
                rows.append(row)
                print(json.dumps(row), flush=True)
                write(rows, args.out)
            return
        for voxel in voxels:
            for group in groups:
                row = {**build(voxel, args.levels, group, work), "command": command}
                rows.append(row)
                print(json.dumps(row), flush=True)
                write(rows, args.out)  # (each row as it comes: a long run stopped keeps what it measured)


def _key(row: dict) -> tuple:
    """A row's identity: a measured chain by voxel and group size, a whole atlas by voxel and ranks."""
    return ("whole", row["voxel_mm"], row["ranks"]) if row.get("whole") else ("chain", row["voxel_mm"], row["group"])


def write(rows: list[dict], folder: Path) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    whole = sorted((r for r in rows if r.get("whole")), key=lambda r: (-r["voxel_mm"], r["ranks"]))
    rows = sorted((r for r in rows if not r.get("whole")), key=lambda r: (-r["voxel_mm"], r["group"]))
    stopped = [r for r in rows if "stopped" in r]
    (folder / "resolution.json").write_text(json.dumps({"rows": rows + whole}, indent=1) + "\n")
    commands = sorted({r["command"] for r in rows + whole})
    lines = [
        "# The skull atlas at 5, 3 and 2 mm: one pose's chain measured, the default atlas extrapolated",
        "",
        f"{machine_line()}; " + "; ".join(f"`{c}`" for c in commands) + " (each row says which: its levels). "
        "The bundled brain, skull 3 mm out; each build its own process.",
        "",
        "## Measured: one pose's chain of levels and the swelling mode",
        "",
        "| voxel mm | nodes | ranks | levels | modes | wall s | setup s | prior and swelling s "
        "| a level in the chain s | peak memory MB (a rank) | atlas.h5 MB |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if "stopped" in r:  # (a build stopped by hand: what was seen, said as such)
            lines.append(
                f"| {r['voxel_mm']:g} | {r['nodes']:,} | {r['group']} (one group) | {r['levels']} | - | "
                f"stopped after {r['stopped_after_s'] / 60:.0f} min | - | - | - | "
                f"{r['resident_mb_when_stopped']:,.0f} when stopped | - |"
            )
            continue
        lines.append(
            f"| {r['voxel_mm']:g} | {r['nodes']:,} | {r['group']} (one group) | {r['levels']} | {r['modes']} | "
            f"{r['wall_s']:.1f} | "
            f"{r['setup_s']:.1f} | {r['prior_and_swelling_s']:.1f} | {r['per_family_mode_s']:.2f} | "
            f"{r['peak_mb']:,.0f} | {r['h5_mb']:.1f} |"
        )
    lines += [f"\nStopped: {r['voxel_mm']:g} mm, {r['stopped']}" for r in stopped]
    rows = [r for r in rows if "stopped" not in r]
    lines += [
        "",
        f"## The default atlas ({DEFAULT_POSES} poses x {DEFAULT_LEVELS} levels + 1 swelling mode), extrapolated",
        "",
        "From the rows above (the module's docstring says how): the setup, then the chains a group solves, one "
        "after another. Disk: the measured file with its modes replaced by the default's, each (N nodes + the fine "
        "surface's points) x 3 x 4 bytes.",
        "",
        "| voxel mm | nodes | " + " | ".join(f"{n} rank{'s' if n > 1 else ''}" for n in RANKS) + " | atlas.h5 GB |",
        "|---|---|" + "---|" * len(RANKS) + "---|",
    ]
    for voxel in sorted({r["voxel_mm"] for r in rows}, reverse=True):
        by_group = {r["group"]: r for r in rows if r["voxel_mm"] == voxel}
        one = by_group.get(1)
        if one is None:
            continue
        plan = extrapolate(one, by_group.get(2))
        cells = [f"{plan[n][0] / 60:.0f} min ({plan[n][1]})" for n in RANKS]
        size_gb = default_size_gb(one, plan["modes"])
        lines.append(f"| {voxel:g} | {one['nodes']:,} | " + " | ".join(cells) + f" | {size_gb:.2f} |")
    if whole:
        lines += [
            "",
            "## The default atlas, measured whole",
            "",
            "The command's wall time, all ranks' groups of one (`mpirun -n R brainshift atlas brain --set "
            "mesh.voxel=V --set skull.gap=0.003`), the largest resident memory of any of its processes.",
            "",
            "| voxel mm | nodes | ranks | modes | left out | wall min | setup s | peak memory MB (a rank) "
            "| atlas.h5 MB | compliance columns (group 0) |",
            "|---|---|---|---|---|---|---|---|---|---|",
        ]
        for r in whole:
            lines.append(
                f"| {r['voxel_mm']:g} | {r['nodes']:,} | {r['ranks']} ({r['groups']} groups) | {r['modes']} | "
                f"{r['left_out']} | {r['wall_s'] / 60:.1f} | {r['setup_s']:.1f} | {r['peak_mb']:,.0f} | "
                f"{r['h5_mb']:.0f} | {r['columns'] if r['columns'] is not None else '-'} |"
            )
    lines += ["", "![the atlas's time against ranks and against nodes](resolution.png)"]
    (folder / "resolution.md").write_text("\n".join(lines) + "\n")
    plot(rows, folder / "resolution.png")
    print("\n".join(lines))


def plot(rows: list[dict], path: Path) -> None:
    """Left: the default atlas's wall time (extrapolated) against ranks, one line a voxel size.
    Right: the measured time of a level against the mesh's nodes, one rank and a group of two."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4))
    for voxel in sorted({r["voxel_mm"] for r in rows}, reverse=True):
        by_group = {r["group"]: r for r in rows if r["voxel_mm"] == voxel}
        if 1 not in by_group:
            continue
        plan = extrapolate(by_group[1], by_group.get(2))
        left.loglog(
            RANKS, [plan[n][0] / 60 for n in RANKS], "o-", label=f"{voxel:g} mm ({by_group[1]['nodes']:,} nodes)"
        )
    left.axhline(20, color="k", ls=":", lw=1, label="20 minutes")
    left.set_xlabel("ranks (one group of one rank each, at most one a pose)")
    left.set_ylabel("default atlas, minutes (extrapolated)")
    left.grid(True, which="both", alpha=0.3)
    left.legend(fontsize=8)
    for group, marker in ((1, "o-"), (2, "s--")):
        mine = sorted((r for r in rows if r["group"] == group), key=lambda r: r["nodes"])
        if mine:
            label = "one rank" if group == 1 else "one group of two ranks"
            right.loglog([r["nodes"] for r in mine], [r["per_family_mode_s"] for r in mine], marker, label=label)
    ones = sorted((r for r in rows if r["group"] == 1), key=lambda r: r["nodes"])
    if ones:
        nodes = [r["nodes"] for r in ones]
        right.loglog(nodes, [ones[0]["per_family_mode_s"] * n / nodes[0] for n in nodes], "k:", lw=1, label="linear")
    right.set_xlabel("nodes")
    right.set_ylabel("a level of a pose's chain, s (measured)")
    right.grid(True, which="both", alpha=0.3)
    right.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
