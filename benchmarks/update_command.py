"""`brainshift update` as a new process on a large atlas: what reading only what it needs
saves. The same command, the same points, on the atlas as written (modes/vertex contiguous:
mapped, pages read as the update touches them, atlas/mode_file.py) and on a copy whose
modes/vertex is chunked a mode a chunk (the reader cannot map it and reads it whole: the
baseline, the same code otherwise). Measured per command, alternating the two: the wall time,
the peak resident memory (the child's rusage), the update's own prepare and update times
(update.json), the bytes read from disk; with --cold the page cache is dropped before each
command (root only), so the disk reads count too.

    python benchmarks/update_command.py --atlas ATLAS [--atlas ATLAS2 ...] [--repeat 5] [--cold] [--out NAME]

Points: 20 pairs on the brain's top, each moved by 1.2x the prior's displacement plus 0.5 mm
noise (seeded). Results: benchmarks/results/NAME.md (default update_command).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fenics_brainshift.bench import machine_line  # noqa: E402
from fenics_brainshift.images import write_markups  # noqa: E402

BRAINSHIFT = str(Path(sys.executable).with_name("brainshift"))


def points(atlas: Path, folder: Path) -> list[str]:
    """The markups' arguments: 20 pairs on the brain's top (atlas.h5 read directly)."""
    with h5py.File(atlas / "atlas.h5", "r") as f:
        xyz, prior, boundary = f["mesh/points"][...], f["prior/vertex"][...], f["boundary/vertices"][...]
        up = -np.asarray(json.loads((atlas / "atlas.json").read_text()).get("gravity", [0, -9.81, 0]), float)
    top = boundary[np.argsort(-(xyz[boundary] @ up))[:400]]
    rng = np.random.default_rng(0)
    picked = rng.choice(top, 20, replace=False)
    labels = [f"P{i}" for i in range(20)]
    write_markups(folder / "pre.mrk.json", labels, xyz[picked] * 1e3)
    moved = xyz[picked] + 1.2 * prior[picked] + rng.normal(0.0, 0.5e-3, (20, 3))
    write_markups(folder / "intra.mrk.json", labels, moved * 1e3)
    return ["--pre", str(folder / "pre.mrk.json"), "--target", str(folder / "intra.mrk.json"), "--noise", "0.5"]


def chunked_copy(atlas: Path, folder: Path) -> Path:
    """The atlas with modes/vertex chunked a mode a chunk (the same numbers and checks)."""
    copy = folder / "chunked"
    copy.mkdir()
    shutil.copy(atlas / "atlas.json", copy / "atlas.json")
    with h5py.File(atlas / "atlas.h5", "r") as src, h5py.File(copy / "atlas.h5", "w") as dst:
        for key, value in src.attrs.items():
            dst.attrs[key] = value
        for name in src:
            if name != "modes":
                src.copy(src[name], dst, name=name)
        modes = src["modes/vertex"]
        chunked = dst.create_dataset("modes/vertex", shape=modes.shape, dtype=modes.dtype, chunks=(1, *modes.shape[1:]))
        for k in range(len(modes)):
            chunked[k] = modes[k]
        for name in src["modes"]:
            if name != "vertex":
                src.copy(src["modes"][name], dst["modes"], name=name)
    return copy


def drop_caches() -> bool:
    try:
        subprocess.run(["sync"], check=True)
        Path("/proc/sys/vm/drop_caches").write_text("1\n")
        return True
    except OSError:
        return False


def pages_in_kb() -> int:
    """The kB read from block devices since boot, every process's (/proc/vmstat's pgpgin)."""
    for line in Path("/proc/vmstat").read_text().splitlines():
        if line.startswith("pgpgin "):
            return int(line.split()[1])
    return 0


def run(atlas: Path, args: list[str], out: Path) -> dict:
    shutil.rmtree(out, ignore_errors=True)
    read_before = pages_in_kb()
    with tempfile.TemporaryFile() as err:
        start = time.perf_counter()
        child = subprocess.Popen(
            [BRAINSHIFT, "update", str(atlas), *args, "--out", str(out)], stdout=subprocess.DEVNULL, stderr=err
        )
        _, status, usage = os.wait4(child.pid, 0)  # (this child's own peak memory)
        wall = time.perf_counter() - start
        child.returncode = os.waitstatus_to_exitcode(status)
        if child.returncode:
            err.seek(0)
            raise SystemExit(f"brainshift update failed: {err.read().decode().strip()}")
    report = json.loads((out / "update.json").read_text())
    return {
        "wall_s": wall,
        "disk_mb": (pages_in_kb() - read_before) / 1024,
        "peak_mb": usage.ru_maxrss / 1024,
        "prepare_ms": report["timings_ms"]["atlas_prepare_ms"],
        "update_ms": report["timings_ms"]["total_ms"],
        "weights_ms": report["timings_ms"]["weights_ms"],
        "skull_rows": (report.get("skull") or {}).get("nodes_with_rows", 0),
        "weights": report["weights"],
    }


def measure(atlas: Path, repeat: int, cold: bool) -> tuple[dict, float]:
    """{way: [a run each repeat]} for one atlas, and how far apart the ways' weights are."""
    with tempfile.TemporaryDirectory(dir=atlas.parent) as tmp:
        tmp = Path(tmp)
        args = points(atlas, tmp)
        ways = {"mapped (as written)": atlas, "read whole (modes chunked)": chunked_copy(atlas, tmp)}
        runs = {name: [] for name in ways}
        for _ in range(repeat):
            for name, folder in ways.items():
                if cold:
                    drop_caches()
                runs[name].append(run(folder, args, tmp / "out"))
    first = runs[next(iter(runs))][0]["weights"]
    return runs, max(np.abs(np.subtract(r["weights"], first)).max() for v in runs.values() for r in v)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--atlas", type=Path, action="append", required=True, help="again for another atlas")
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--cold", action="store_true", help="drop the page cache before each command (root)")
    parser.add_argument("--out", default="update_command")
    options = parser.parse_args()
    if options.cold and not drop_caches():
        raise SystemExit("--cold: the page cache cannot be dropped here (root on Linux only)")
    command = " ".join(f"--atlas {chr(65 + i)}" for i in range(len(options.atlas)))
    lines = [
        "# `brainshift update` as a new process: mapped modes against modes read whole",
        "",
        f"{machine_line()}; `python benchmarks/update_command.py {command} --repeat {options.repeat}"
        f"{' --cold' if options.cold else ''}`. 20 point pairs; medians of {options.repeat}, the two ways "
        "alternating; "
        + ("the page cache dropped before each command." if options.cold else "from the page cache (warm)."),
        "",
        "| atlas | atlas.h5's modes | wall s | peak memory MB | read from disk MB | prepare ms | update ms "
        "| of it: the weights ms | nodes with skull rows |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    notes = []
    for i, atlas in enumerate(options.atlas):
        info = json.loads((atlas / "atlas.json").read_text())
        size_mb = (atlas / "atlas.h5").stat().st_size / 1e6
        runs, same = measure(atlas, options.repeat, options.cold)
        name = chr(65 + i)
        notes.append(
            f"{name}: {info.get('scene', '?')} with {' '.join(info.get('set', []))} ({info['modes']} modes, "
            f"{info['nodes']:,} nodes; atlas.h5 {size_mb:,.0f} MB)"
            + (f", {info['standin_note']}" if "standin_note" in info else "")
            + f"; the weights the same both ways to {same:.1g}."
        )
        for way, values in runs.items():
            keys = ("wall_s", "disk_mb", "prepare_ms", "update_ms", "weights_ms", "skull_rows")
            med = {k: statistics.median(r[k] for r in values) for k in keys}
            lines.append(
                f"| {name} | {way} | {med['wall_s']:.2f} | {max(r['peak_mb'] for r in values):,.0f} | "
                f"{med['disk_mb']:,.0f} | {med['prepare_ms']:.0f} | {med['update_ms']:.0f} | "
                f"{med['weights_ms']:.0f} | {med['skull_rows']:,.0f} |"
            )
    lines += [
        "",
        *notes,
        "",
        "Peak memory: the largest resident set of the way's commands (wait4's rusage of each; a mapped file's pages "
        "count once touched, and the kernel maps those already cached around each one touched). Read from disk: "
        "/proc/vmstat's pgpgin over the command, every process's (the machine otherwise idle; with a warm cache "
        "about 0), the Python libraries' too. Prepare: the atlas made ready once a process (update.json's "
        "atlas_prepare_ms); update: the update itself (its total_ms), of it the weights (cross-validation and "
        "the fit; the rest is leave-one-out and the spread).",
        "",
    ]
    path = ROOT / "benchmarks" / "results" / f"{options.out}.md"
    path.write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    main()
