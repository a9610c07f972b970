"""How an atlas's modes are best kept in atlas.h5: contiguous (what atlas/store.py writes),
chunked a mode a chunk or a block of nodes a chunk, and compressed (gzip or lzf, with the byte
shuffle): the file's size, the time to write it, to read every mode, and to read the modes at
the nodes of the cells that hold 20 points on the brain's top (what an update needs before
the whole field).

Writes benchmarks/results/atlas_storage.md.

    python benchmarks/atlas_storage.py --atlas ATLAS [--repeat 5]

ATLAS: any atlas folder (`brainshift atlas ...`). Each time is the median of the repeats, the
layouts alternating; the file is read from the page cache (written just before), so the times
are decoding and copying, not the disk.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fenics_brainshift.atlas import store  # noqa: E402
from fenics_brainshift.atlas.locate import MeshLocator  # noqa: E402
from fenics_brainshift.bench import machine_line  # noqa: E402

NODE_BLOCK = 4096


def layouts(shape: tuple) -> dict[str, dict]:
    modes, nodes, _ = shape
    by_mode = (1, nodes, 3)
    by_nodes = (modes, min(NODE_BLOCK, nodes), 3)
    return {
        "contiguous (store.py)": {},
        "a mode a chunk": {"chunks": by_mode},
        "a mode a chunk, shuffle + gzip 1": {"chunks": by_mode, "shuffle": True, "compression": "gzip",
                                             "compression_opts": 1},
        "a mode a chunk, shuffle + lzf": {"chunks": by_mode, "shuffle": True, "compression": "lzf"},
        f"{NODE_BLOCK} nodes a chunk, shuffle + lzf": {"chunks": by_nodes, "shuffle": True, "compression": "lzf"},
    }  # fmt: skip


def near_points(atlas: store.Atlas, count: int = 20) -> np.ndarray:
    """The vertices of the cells holding ``count`` points just under the brain's top (sorted)."""
    up = atlas.points[:, 2]
    top = atlas.points[up > np.quantile(up, 0.97)]
    picked = top[np.random.default_rng(0).choice(len(top), count, replace=False)]
    inside = picked - np.array([0.0, 0.0, 2e-3])
    cells, _, _ = MeshLocator(atlas.points, atlas.tetrahedra).weights(inside)
    return np.unique(cells.ravel())


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--atlas", required=True, type=Path)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    args = parser.parse_args(argv)
    atlas = store.read(args.atlas)
    U = atlas.vertex_modes.astype(np.float32)
    rows_wanted = near_points(atlas)
    ways = layouts(U.shape)
    times = {w: {"write": [], "read": [], "near": []} for w in ways}
    sizes = {}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.repeat):
            for way, options in ways.items():
                path = Path(tmp) / "modes.h5"
                start = time.perf_counter()
                with h5py.File(path, "w") as f:
                    f.create_dataset("modes", data=U, **options)
                times[way]["write"].append(time.perf_counter() - start)
                sizes[way] = path.stat().st_size
                start = time.perf_counter()
                with h5py.File(path, "r") as f:
                    whole = f["modes"][...]
                times[way]["read"].append(time.perf_counter() - start)
                start = time.perf_counter()
                with h5py.File(path, "r") as f:
                    near = f["modes"][:, rows_wanted, :]
                times[way]["near"].append(time.perf_counter() - start)
                assert np.array_equal(whole, U) and np.array_equal(near, U[:, rows_wanted])
    lines = [
        "# An atlas's modes in atlas.h5: contiguous, chunked, compressed",
        "",
        f"{machine_line()}; `python benchmarks/atlas_storage.py --atlas ATLAS --repeat {args.repeat}`; ATLAS: "
        f"{atlas.info.get('scene')} with {' '.join(atlas.info.get('set', []))} ({U.shape[0]} modes, {U.shape[1]:,} "
        f"nodes; the modes {U.nbytes / 2**20:.1f} MB in single precision). Near the points: the {len(rows_wanted)} "
        "vertices of the cells holding 20 points 2 mm under the brain's top. Medians; read from the page cache.",
        "",
        "| layout | size, of contiguous | write ms | read every mode ms | read the nodes near the points ms |",
        "|---|---|---|---|---|",
    ]
    plain = sizes["contiguous (store.py)"]
    for way in ways:
        t = {k: 1e3 * statistics.median(v) for k, v in times[way].items()}
        lines.append(f"| {way} | {sizes[way] / plain:.2f} | {t['write']:.1f} | {t['read']:.1f} | {t['near']:.1f} |")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "atlas_storage.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
