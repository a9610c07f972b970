"""The tables and the Pareto plot of a benchmark sweep, and the machine line every result
file starts with."""

from __future__ import annotations

import csv
from pathlib import Path

from .. import compat


def read_rows(path: Path) -> list[dict]:
    """The rows of an earlier sweep's CSV, numbers as numbers (none if there is no file)."""
    if not path.exists():
        return []
    integers = {"nodes", "dofs", "steps", "solves"}
    with open(path, newline="") as f:
        return [
            {k: (v if k in ("config", "family") else int(v) if k in integers else float(v)) for k, v in row.items()}
            for row in csv.DictReader(f)
        ]


def pareto_front(rows: list[dict]) -> list[int]:
    """Indices of the rows no other row beats in both run time and max error."""
    front = []
    for i, r in enumerate(rows):
        dominated = any(
            o["total_s"] <= r["total_s"]
            and o["max_error_mm"] <= r["max_error_mm"]
            and (o["total_s"] < r["total_s"] or o["max_error_mm"] < r["max_error_mm"])
            for o in rows
        )
        if not dominated:
            front.append(i)
    return sorted(front, key=lambda i: rows[i]["total_s"])


def write(rows: list[dict], ref, bench: str, level: str, out: Path, only=None) -> None:
    out.mkdir(parents=True, exist_ok=True)
    stem = out / f"time_vs_error_{bench}"
    with open(stem.with_suffix(".csv"), "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    front = set(pareto_front(rows))
    by_name = {r["config"]: r for r in rows}
    paper, naive = by_name.get("paper-equivalent"), by_name.get("naive loop")
    command = f"brainshift bench --scene {bench}" + ("" if level == "full" else f" --{level}")
    lines = [
        f"# Run time against error: {bench}\n",
        f"{machine_line()}, DOLFINx {compat.DOLFINX_VERSION}; `{command}`. Serial. Error against {ref.config.name} "
        f"({ref.nodes} nodes, {ref.dofs} dofs) at fixed sample points; time from scene to answer "
        f"(mesh, forms, factor or preconditioner, solves; the form cache warm). * = on the Pareto front.\n",
        "| configuration | varies | nodes | dofs | steps | solves | setup (s) | solve (s) | total (s) | "
        "max error (mm) | RMS error (mm) | probe error (mm) | speed-up on the paper-equivalent |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for i, r in enumerate(rows):
        speed = f"{paper['total_s'] / r['total_s']:.1f}" if paper else ""
        lines.append(
            f"| {r['config']}{' *' if i in front else ''} | {r['family']} | {r['nodes']} | {r['dofs']} | "
            f"{r['steps']} | {r['solves']} | {r['setup_s']:.2f} | {r['solve_s']:.2f} | {r['total_s']:.2f} | "
            f"{r['max_error_mm']:.3f} | {r['rms_error_mm']:.3f} | {r['probe_error_mm']:.3f} | {speed} |"
        )
    if paper and naive:
        lines.append(
            f"\nThe naive loop takes {naive['total_s']:.1f} s, the paper-equivalent {paper['total_s']:.1f} s "
            f"(run-time ratio naive / paper-equivalent {naive['total_s'] / paper['total_s']:.2f}); the fastest "
            f"configuration with at most the paper-equivalent's error: " + _best_line(rows, paper)
        )
    if only:
        lines.append(
            f"\nRows {', '.join(only)} were (re)measured later with `--only` (and the reference again); "
            f"the others are from the earlier run, as they were."
        )
    stem.with_suffix(".md").write_text("\n".join(lines) + "\n")
    plot_pareto(rows, sorted(front, key=lambda i: rows[i]["total_s"]), stem.with_suffix(".png"), bench)


def _best_line(rows: list[dict], paper: dict) -> str:
    ok = [r for r in rows if r["max_error_mm"] <= 1.01 * paper["max_error_mm"]]
    best = min(ok, key=lambda r: r["total_s"])
    return (
        f"{best['config']}, {best['total_s']:.2f} s ({paper['total_s'] / best['total_s']:.0f}x faster, "
        f"max error {best['max_error_mm']:.3f} mm against {paper['max_error_mm']:.3f} mm)."
    )


def plot_pareto(rows: list[dict], front: list[int], path: Path, bench: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 5))
    families = sorted({r["family"] for r in rows})
    for k, fam in enumerate(families):
        sel = [r for r in rows if r["family"] == fam]
        ax.scatter(
            [r["total_s"] for r in sel], [r["max_error_mm"] for r in sel], label=fam, s=36, marker="os^vDP*"[k % 7]
        )
    ax.plot(
        [rows[i]["total_s"] for i in front], [rows[i]["max_error_mm"] for i in front], "k--", lw=1, label="Pareto front"
    )
    for r in rows:
        if r["family"] == "baseline":
            ax.annotate(
                r["config"], (r["total_s"], r["max_error_mm"]), fontsize=8, xytext=(4, 4), textcoords="offset points"
            )
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("run time, scene to answer (s)")
    ax.set_ylabel("max displacement error (mm)")
    ax.set_title(f"{bench}: run time against error (one point per configuration)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def machine_line() -> str:
    """The machine a result was measured on, for a results file: CPU, cores, memory, OS,
    DOLFINx and PETSc versions."""
    import os
    import platform

    cpu = "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores, {platform.system()} {platform.release()}"
