"""`brainshift update` against the scene's own prediction and `brainshift fit`, on operations the
atlas does not contain exactly; and what the atlas and the update cost. One process, one rank.

The atlas: the bundled brain (linear, no skull) at --voxel, the default family (14 levels x 25
poses) and the whole-brain swelling mode. Each operation is the settled state of a scene built
on its own by the full model: a level and a pose between the atlas's samples, the neo-Hookean
material, a rigid skull 3 mm out (contact), a swelling region the atlas does not have, a
stiffer brain. Measured: 20 points on the exposed cortex (the mesh's surface nodes with
y > 30 mm, anterior: up when supine) with 0.5 mm noise per axis. Error at held-out interior
points: the mesh's nodes off the surface within 40 mm of the craniotomy's centre (the deep
tissue below it), and over every node. `brainshift fit` fits fluid.level, material.G and
gravity.angle_z to the same points (its forward model: the same scene). Writes
benchmarks/results/update.{csv,md}.

--skull GAP (m): the scene, and so the atlas, every operation and the fit, with a rigid skull
GAP out: every mode a contact state, the update's skull rows in every fit (its cost with them),
into benchmarks/results/update_skull.{csv,md}.

--atlas FOLDER: an atlas `brainshift atlas` wrote for the same scene (--voxel, --skull), read
instead of built (its build's time is the one reported, from its atlas.json).

--no-fit: no `brainshift fit` (its columns "-"): at 3 mm its dozens of full-model solves per
operation would take hours; the update's own numbers are unchanged.

    python benchmarks/update.py [--voxel 0.005] [--skull 0.003] [--atlas FOLDER] [--no-fit]
"""

from __future__ import annotations

import argparse
import csv
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from mpi4py import MPI

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fenics_brainshift import load_scene, logs  # noqa: E402
from fenics_brainshift.atlas import combine, store  # noqa: E402
from fenics_brainshift.atlas.build import build  # noqa: E402
from fenics_brainshift.atlas.update import prepare, update  # noqa: E402
from fenics_brainshift.bench import machine_line  # noqa: E402
from fenics_brainshift.data import scene_path  # noqa: E402
from fenics_brainshift.fit import ForwardModel, Target, fit, fit_parameters  # noqa: E402
from fenics_brainshift.fit.parameters import rotated_gravity  # noqa: E402
from fenics_brainshift.outputs.vertices import GlobalVertices  # noqa: E402
from fenics_brainshift.runner import Simulation  # noqa: E402

NOISE = 0.5e-3
POINTS = 20
BOOTSTRAP = 30  # resamplings of `brainshift update --bootstrap`, timed and its spread judged beside the posterior's
DEEP = 0.040  # m from the craniotomy's centre
SWELLING = '\n[[swelling]]\nvolume_change = 0.06\nwhere = "(x-0.03)**2 + (y-0.03)**2 + (z-0.02)**2 < 0.025**2"\n'
OPERATIONS = {  # name: (scene overrides besides the pose, pose and level, extra scene text)
    "between samples": ([], {"fluid.level": 0.0325, "gravity.angle_z": 3.0, "gravity.angle_x": -4.0}, ""),
    "neo-Hookean": (["material.model=neo-hookean"], {"fluid.level": 0.025, "gravity.angle_z": 5.0}, ""),
    "skull 3 mm": (["skull.gap=0.003"], {"fluid.level": 0.02, "gravity.angle_z": -6.0}, ""),
    "regional swelling +6 %": ([], {"fluid.level": 0.035, "gravity.angle_x": 4.0}, SWELLING),
    "stiffer (G x 1.5)": (["material.G=4500"], {"fluid.level": 0.015, "gravity.angle_z": 8.0}, ""),
}


def scene_file(extra: str, folder: Path) -> str:
    """The bundled brain scene with text appended (its relative paths made absolute)."""
    if not extra:
        return "brain"
    here = scene_path("brain").parent
    text = scene_path("brain").read_text().replace('"../', f'"{here.parent}/') + extra
    path = folder / "brain_swelling.toml"
    path.write_text(text)
    return str(path)


def truth_state(base: list[str], overrides: list[str], values: dict, extra: str, folder: Path):
    g = rotated_gravity([0.0, -9.81, 0.0], values)
    sets = base + overrides + [f"gravity.vector=[{g[0]}, {g[1]}, {g[2]}]", f"fluid.level={values['fluid.level']}"]
    scene = load_scene(scene_file(extra, folder), sets)
    sim = Simulation(scene, MPI.COMM_WORLD)
    sim.setup()
    t = time.perf_counter()
    sim.solve_to_settled(scene.time.end)
    seconds = time.perf_counter() - t
    vertices = GlobalVertices(sim.model.mesh)
    u = vertices.values(sim.u)
    sim.destroy()
    return vertices.points, u, seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--voxel", type=float, default=0.005)
    parser.add_argument("--skull", type=float, default=None, help="a rigid skull this far out (m)")
    parser.add_argument("--atlas", default=None, help="read this atlas folder instead of building one")
    parser.add_argument("--no-fit", action="store_true", help="skip brainshift fit (its columns '-')")
    parser.add_argument("--out", default=None)
    args = parser.parse_args()
    logs.configure("WARNING")
    base = [f"mesh.voxel={args.voxel}", "time.mode=quasi-static"]
    if args.skull is not None:
        base.append(f"skull.gap={args.skull}")
    args.out = args.out or str(ROOT / "benchmarks" / "results" / ("update" if args.skull is None else "update_skull"))
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    folder = Path(tempfile.mkdtemp(prefix="brainshift-update-bench-"))  # (the swelling scene's file)

    start = time.perf_counter()
    if args.atlas is None:
        atlas, seconds = build(load_scene("brain", base), {}, MPI.COMM_WORLD)
        atlas_s = time.perf_counter() - start
    else:  # (built by `brainshift atlas brain --set mesh.voxel=... [--set skull.gap=...]`)
        atlas = store.read(args.atlas)
        seconds = {k: atlas.info[k] for k in ("setup_s", "modes_s")}
        atlas_s = seconds["setup_s"] + seconds["modes_s"]
    prepare_s = prepare(atlas)  # (once per atlas, as `brainshift update` does on loading it)
    points = atlas.points
    boundary = np.zeros(len(points), dtype=bool)
    boundary[atlas.boundary.vertices] = True
    exposed = np.flatnonzero(boundary & (points[:, 1] > 0.03))
    centre = points[exposed].mean(axis=0)
    deep = np.flatnonzero(~boundary & (np.linalg.norm(points - centre, axis=1) < DEEP))
    if not args.no_fit:
        forward = ForwardModel(load_scene("brain", base))
        names = ["fluid.level", "material.G", "gravity.angle_z"]
        params = fit_parameters(forward.scene, names, forward.heights())
        fit_vertices = GlobalVertices(forward.model.mesh)
    rows = []
    for seed, (name, (overrides, values, extra)) in enumerate(OPERATIONS.items()):
        truth_points, truth, truth_s = truth_state(base, overrides, values, extra, folder)
        assert np.abs(truth_points - points).max() < 1e-9  # the same vertices, in the same order
        rng = np.random.default_rng(seed)
        picked = rng.choice(exposed, POINTS, replace=False)
        pre = points[picked]
        measured = pre + truth[picked] + rng.normal(0.0, NOISE, pre.shape)
        target = Target(measured, pre, [f"p{i}" for i in range(POINTS)])
        updates = [update(atlas, target, NOISE) for _ in range(5)]  # (the spread from the posterior)
        result = updates[-1]
        bootstrapped = [update(atlas, target, NOISE, samples=BOOTSTRAP) for _ in range(3)]
        combine.WARM_START = False  # the baseline in the same run: every refit by NNLS from scratch
        scratch = [update(atlas, target, NOISE) for _ in range(3)]
        combine.WARM_START = True
        same = max(
            float(np.abs(scratch[-1].weights - result.weights).max()),
            float(np.abs(scratch[-1].spread - result.spread).max()) / max(float(result.spread.max()), 1e-300),
        )
        if args.no_fit:
            fitted, fit_s, u_fit = None, float("nan"), np.full_like(truth, np.nan)
        else:
            t = time.perf_counter()
            fitted = fit(forward, target, params, NOISE)
            fit_s = time.perf_counter() - t
            u_fit = fit_vertices.values(forward.sim.u)

        def errors(u):
            e = np.linalg.norm(u - truth, axis=1) * 1e3
            return float(e[deep].mean()), float(e.mean()), float(e[picked].mean())

        prior, updated, fitted_e = errors(atlas.prior_vertex), errors(result.displacement), errors(u_fit)
        rows.append(
            {
                "operation": name,
                "truth_shift_max_mm": float(np.linalg.norm(truth, axis=1).max() * 1e3),
                "prior_deep_mm": prior[0],
                "fit_deep_mm": fitted_e[0],
                "update_deep_mm": updated[0],
                "prior_all_mm": prior[1],
                "fit_all_mm": fitted_e[1],
                "update_all_mm": updated[1],
                "update_points_mm": updated[2],
                "update_loo_rms_mm": float(np.sqrt(np.mean(result.leave_one_out**2)) * 1e3),
                "update_spread_deep_mm": float(result.spread[deep].mean() * 1e3),
                "bootstrap_spread_deep_mm": float(bootstrapped[-1].spread[deep].mean() * 1e3),
                # the spread's meaning: how often the true error at a deep node is inside twice the spread
                "posterior_covers_deep": float(
                    np.mean(np.linalg.norm(result.displacement - truth, axis=1)[deep] < 2 * result.spread[deep])
                ),
                "bootstrap_covers_deep": float(
                    np.mean(
                        np.linalg.norm(bootstrapped[-1].displacement - truth, axis=1)[deep]
                        < 2 * bootstrapped[-1].spread[deep]
                    )
                ),
                "update_total_bootstrap_ms": float(np.median([r.seconds["total_ms"] for r in bootstrapped])),
                "update_fit_ms": float(np.median([r.seconds["fit_ms"] for r in updates])),
                "update_total_ms": float(np.median([r.seconds["total_ms"] for r in updates])),
                "update_total_scratch_ms": float(np.median([r.seconds["total_ms"] for r in scratch])),
                "warm_against_scratch": same,
                "fit_s": fit_s,
                "fit_solves": fitted.solves if fitted else 0,
                "truth_solve_s": truth_s,
                "skull_rows": int(result.skull.get("nodes_with_rows", 0)),
            }
        )
        print(rows[-1], flush=True)
    if not args.no_fit:
        forward.destroy()
    out = Path(args.out)
    with open(out.with_suffix(".csv"), "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    mean = {k: float(np.mean([r[k] for r in rows])) for k in rows[0] if k != "operation"}
    lines = [
        "# The update against the scene's prediction and `brainshift fit`",
        "",
        f"{machine_line()}; one rank; `python benchmarks/update.py --voxel {args.voxel:g}"
        f"{'' if args.skull is None else f' --skull {args.skull:g}'}"
        f"{'' if args.atlas is None else ' --atlas ATLAS'}{' --no-fit' if args.no_fit else ''}`"
        + (
            ""
            if args.atlas is None
            else " (ATLAS: `brainshift atlas brain` with the same --set, its build timed by itself)"
        )
        + "; the "
        f"{args.voxel * 1e3:g} mm brain ({len(points)} nodes)"
        + (
            ""
            if args.skull is None
            else f", a rigid skull {args.skull * 1e3:g} mm out in the atlas, every operation and the fit"
        )
        + f". Atlas: {len(atlas.scenarios)} modes "
        f"({int(atlas.family.sum())} drain/pose states + {len(atlas.scenarios) - int(atlas.family.sum())} swelling) "
        f"in {atlas_s:.1f} s ({seconds['setup_s']:.1f} s setup, {seconds['modes_s']:.1f} s modes, "
        f"{atlas.info['settled_states']} settled states). {POINTS} points on the exposed cortex, "
        f"{NOISE * 1e3:g} mm noise; deep: {len(deep)} interior nodes within {DEEP * 1e3:g} mm of the "
        f"craniotomy's centre. Errors: mean |u - u_true| (mm).",
        "",
        "| operation | true shift max | prior deep | fit deep | **update deep** | prior all | fit all | "
        "update all | update LOO RMS | spread deep: posterior / bootstrap | error < 2 spread: posterior / bootstrap | "
        "update fit / total ms | with bootstrap ms | total from scratch ms | fit s |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows + [dict(mean, operation="**mean**")]:
        lines.append(
            f"| {r['operation']} | {r['truth_shift_max_mm']:.1f} | {r['prior_deep_mm']:.2f} | "
            f"{_or_dash(r['fit_deep_mm'], '.2f')} | **{r['update_deep_mm']:.2f}** | {r['prior_all_mm']:.2f} | "
            f"{_or_dash(r['fit_all_mm'], '.2f')} | {r['update_all_mm']:.2f} | {r['update_loo_rms_mm']:.2f} | "
            f"{r['update_spread_deep_mm']:.2f} / {r['bootstrap_spread_deep_mm']:.2f} | "
            f"{r['posterior_covers_deep']:.0%} / {r['bootstrap_covers_deep']:.0%} | "
            f"{r['update_fit_ms']:.1f} / {r['update_total_ms']:.0f} | {r['update_total_bootstrap_ms']:.0f} | "
            f"{r['update_total_scratch_ms']:.0f} | {_or_dash(r['fit_s'], '.1f')} |"
        )
    lines += [
        "",
        "update fit / total: the fit's rounds after cross-validation (which fits every point at each "
        "alpha: the rounds start from its fit at the chosen one, and re-linearise the skull's rows) / the "
        "whole update, with cross-validation, "
        "leave-one-out and the spread from the weights' posterior (the default; median of 5), the atlas "
        f"prepared once on loading it ({prepare_s * 1e3:.0f} ms: atlas/update.py prepare); with bootstrap: the "
        f"same with the spread from a {BOOTSTRAP}-sample bootstrap (`--bootstrap {BOOTSTRAP}`, median of 3); "
        "error < 2 spread: the deep nodes whose true error is inside twice the reported spread; total "
        "from scratch: the whole update with every refit solved by NNLS "
        "from scratch (atlas/combine.py WARM_START = False; median of 3), the baseline of the warm-started "
        f"refits (the same weights and spread to {max(r['warm_against_scratch'] for r in rows):.1e}). "
        + (
            "fit: not run (--no-fit)."
            if args.no_fit
            else "fit s: `brainshift fit`'s calibration (3 parameters) on the same points, in the same run."
        )
        + (
            ""
            if args.skull is None
            else " Skull rows: the boundary nodes near the skull whose room the "
            f"update keeps as a constraint, {min(r['skull_rows'] for r in rows)}-"
            f"{max(r['skull_rows'] for r in rows)} in these operations."
        ),
    ]
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print(f"wrote {out}.md and .csv")


def _or_dash(value: float, spec: str) -> str:
    return "-" if np.isnan(value) else format(value, spec)


if __name__ == "__main__":
    main()
