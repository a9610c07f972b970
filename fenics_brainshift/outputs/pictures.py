"""Pictures and plots of a finished run, made from its output files on rank 0.

- deformed.png: the body at the last output time, warped by its displacement and coloured
  by |u| (mm), the undeformed body as a translucent grey ghost, the fluid level as a translucent
  plane (the paper's Figs. 14 and 18), gravity as an arrow; removed cells (tissue = 0) are left
  out. Where the run wrote a fine surface (surface_final.vtk) that smooth surface is drawn
  instead of the voxel mesh's staircase; a mesh made from an image (RAS) gets its anatomical
  directions marked (R/L, A/P, S/I); the probes are red points where the shift took them. The
  colour bar runs from 0 to a round number.
- probes.png: each probe's displacement along gravity against time, the fluid level on a
  second axis (the paper's Fig. 16); settled states (quasi-static) as points, not lines; many
  probes named beside the plot.

Rendering is off-screen (pyvista/VTK); matplotlib draws the plots. Both are optional extras:
without pyvista the picture is skipped with a log line, never an error.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..logs import get_logger
from .run_folder import read_last_state

log = get_logger("viz")


def deformed_picture(
    out: Path, gravity, level: float | None, path: Path | None = None, anatomical: bool = False
) -> Path | None:
    """deformed.png of a run folder; None when pyvista is not installed."""
    try:
        import pyvista as pv
    except ImportError:
        log.info("pyvista not installed: no deformed.png (pip install pyvista)")
        return None
    pv.OFF_SCREEN = True
    points, tets, u, tissue = read_last_state(out / "displacement.xdmf")
    if tissue is not None:
        tets = tets[tissue > 0.5]
    fine = out / "surface_final.vtk"
    deformed, undeformed = _surfaces(pv, points, tets, u, fine)
    g = np.asarray(gravity, dtype=float)
    up = -g / np.linalg.norm(g) if np.linalg.norm(g) > 0 else np.array([0.0, 0.0, 1.0])
    plotter = pv.Plotter(off_screen=True, window_size=(1000, 750))
    plotter.set_background("white")
    top = nice_ceiling(float(np.max(deformed.point_data["displacement (mm)"], initial=0.0)))
    plotter.add_mesh(
        deformed,
        scalars="displacement (mm)",
        cmap="viridis",
        smooth_shading=True,
        clim=[0.0, top],
        scalar_bar_args={
            "title": "displacement (mm)\n",
            "color": "black",
            "vertical": True,
            "n_labels": 5,
            "fmt": "%.3g",
            "title_font_size": 18,
            "label_font_size": 15,
            "position_x": 0.11,
            "position_y": 0.2,
            "height": 0.5,
            "width": 0.06,
        },
    )
    plotter.add_mesh(undeformed, color="lightgray", opacity=0.3)  # the undeformed body, as a ghost
    lo, hi = points.min(axis=0), points.max(axis=0)
    side, screen_up = _view(up, anatomical)
    if np.linalg.norm(g) > 0:
        _gravity_arrow(pv, plotter, lo, hi, up, side, screen_up, anatomical)
    if anatomical:
        _anatomical_letters(plotter, lo, hi, side)
    skull, landmarks = _skull_and_probes(pv, plotter, out, anatomical)
    if level is not None and np.isfinite(level):
        centre = 0.5 * (lo + hi)
        size = 1.4 * float(np.linalg.norm(hi - lo))
        plane = pv.Plane(center=centre + (level - centre @ up) * up, direction=up, i_size=size, j_size=size)
        plotter.add_mesh(plane, color="#3a7bd5", opacity=0.25, lighting=False)  # (blue seen edge-on too)
    focus = points.mean(axis=0)
    distance = 2.5 * float(np.linalg.norm(hi - lo))
    lift = 0.1 if anatomical else 0.35  # (a slightly raised viewpoint; a patient's seen almost square on)
    plotter.camera_position = [
        tuple(focus + distance * (0.85 * side + lift * screen_up)),
        tuple(focus),
        tuple(screen_up),
    ]
    a = int(np.argmax(np.abs(side)))
    seen = f"seen from {'LRPAIS'[2 * a + (side[a] > 0)]}; " if anatomical else ""
    plotter.add_text(
        seen + ("fine surface" if fine.is_file() else "deformed body") + " coloured by displacement; "
        "undeformed in grey"
        + ("; fluid level: blue plane" if level is not None else "")
        + ("; probes: red" if landmarks else "")
        + ("; skull: grey cage" if skull else ""),
        font_size=12,
        color="black",
    )
    path = path or out / "deformed.png"
    plotter.screenshot(str(path))
    plotter.close()
    return path


def _surfaces(pv, points: np.ndarray, tets: np.ndarray, u: np.ndarray, fine: Path):
    """(deformed, undeformed) surfaces to draw: the run's smooth fine surface where it wrote one
    (Taubin-smoothed for the picture only, volume-keeping), else the voxel mesh's boundary; the
    deformed one carries "displacement (mm)"."""
    if not fine.is_file():
        grid = pv.UnstructuredGrid({pv.CellType.TETRA: tets}, points)
        moved = grid.copy()
        moved.points = points + u
        moved.point_data["displacement (mm)"] = np.linalg.norm(u, axis=1) * 1e3
        return moved.extract_surface(algorithm="dataset_surface"), grid.extract_surface(algorithm="dataset_surface")
    import meshio

    mesh = meshio.read(fine)  # legacy VTK is big-endian: to native floats, or VTK reads garbage
    d = np.asarray(mesh.point_data["displacement"], dtype=np.float64)
    fine_points = np.asarray(mesh.points, dtype=np.float64)
    triangles = np.asarray(mesh.cells_dict["triangle"], dtype=np.int64)
    deformed = pv.PolyData.from_regular_faces(fine_points, triangles).smooth_taubin(n_iter=40, pass_band=0.05)
    deformed.point_data["displacement (mm)"] = np.linalg.norm(d, axis=1) * 1e3
    undeformed = pv.PolyData.from_regular_faces(fine_points - d, triangles).smooth_taubin(n_iter=40, pass_band=0.05)
    return deformed, undeformed


def _view(up: np.ndarray, anatomical: bool) -> tuple[np.ndarray, np.ndarray]:
    """(the direction the camera looks from, the screen's up). Horizontally along the first
    axis across gravity (x: from the side for a supine head in RAS and for the cube); for a
    patient a standard anatomical view: superior at the top (anterior when gravity is along
    the head's axis), seen along the axis most across gravity (a supine head from the side, a
    head on its side from the front), so that the sag runs across the picture."""
    if not anatomical:
        axis = next(a for a in np.eye(3) if abs(a @ up) < 0.9)
        side = axis - (axis @ up) * up
        return side / np.linalg.norm(side), up
    screen_up = np.eye(3)[2] if abs(up[2]) < 0.9 else np.eye(3)[1]
    others = [a for a in np.eye(3) if abs(a @ screen_up) < 0.5]
    side = min(others, key=lambda a: abs(a @ up))
    return (side if side @ np.array([1.0, 1.0, 0.0]) >= 0 else -side), screen_up  # from the right, or the front


def _gravity_arrow(pv, plotter, lo, hi, up, side, screen_up, anatomical: bool) -> None:
    """Gravity as an arrow beside the body (above it for a patient's view, where gravity may
    run across the screen)."""
    centre, extent = 0.5 * (lo + hi), float(np.linalg.norm(hi - lo))
    across = np.cross(screen_up, side)  # left to right on the screen
    start = centre + (
        0.45 * extent * screen_up + 0.25 * extent * up if anatomical else 0.55 * extent * across + 0.3 * extent * up
    )
    plotter.add_mesh(pv.Arrow(start=start, direction=-up, scale=0.25 * extent), color="black")
    plotter.add_point_labels(
        [start + 0.04 * extent * up],
        ["gravity"],
        font_size=14,
        text_color="black",
        shape=None,
        show_points=False,
        always_visible=True,
    )


def _anatomical_letters(plotter, lo, hi, side) -> None:
    """RAS: a letter beyond the body on each axis not along the line of sight."""
    centre, extent = 0.5 * (lo + hi), float(np.linalg.norm(hi - lo))
    labels, where = [], []
    for a, (minus, plus) in enumerate((("L", "R"), ("P", "A"), ("I", "S"))):
        if abs(np.eye(3)[a] @ side) > 0.9:
            continue
        for sign, letter in ((-1, minus), (1, plus)):
            p = centre.copy()
            p[a] = (hi if sign > 0 else lo)[a] + sign * 0.1 * extent
            labels.append(letter)
            where.append(p)
    plotter.add_point_labels(
        np.array(where),
        labels,
        font_size=26,
        text_color="firebrick",
        bold=True,
        shape=None,
        show_points=False,
        always_visible=True,
    )


def _skull_and_probes(pv, plotter, out: Path, anatomical: bool) -> tuple[bool, bool]:
    """The skull the run used (skull.stl, mm RAS as Slicer reads it) as a faint cage, and the
    probes where the shift took them (probes_final.mrk.json); whether each was drawn."""
    skull, landmarks = out / "skull.stl", out / "probes_final.mrk.json"
    if skull.is_file():
        from ..surfaces.files import read_surface

        skull_points, skull_triangles = read_surface(skull, 1e-3)
        plotter.add_mesh(
            pv.PolyData.from_regular_faces(skull_points, skull_triangles),
            color="dimgray",
            style="wireframe",
            opacity=0.15,
        )
    if landmarks.is_file():
        from ..images.frames import read_markups

        names, where_mm = read_markups(landmarks, "probes_final.mrk.json")
        plotter.add_points(where_mm * 1e-3, color="crimson", point_size=12, render_points_as_spheres=True)
        if len(names) <= 12 and not anatomical:  # names cover a patient's picture: in probes_final.mrk.json
            plotter.add_point_labels(
                where_mm * 1e-3,
                names,
                font_size=12,
                text_color="crimson",
                shape=None,
                show_points=False,
                always_visible=True,
            )
    return skull.is_file(), landmarks.is_file()


PICTURES = ("probes.png", "deformed.png")


def nice_ceiling(value: float) -> float:
    """The smallest of 1, 2, 2.5, 5 x 10^k at least ``value`` (a colour bar's top: 0 to a round
    number, not 2.33e-18 to 1.9737)."""
    if not value > 0:
        return 1.0
    power = 10.0 ** np.floor(np.log10(value))
    return float(next(m * power for m in (1.0, 2.0, 2.5, 5.0, 10.0) if m * power >= value * (1 - 1e-12)))


LEGEND_INSIDE = 6  # probes named in a legend under the plot; more go beside it


def probe_plot(
    out: Path, gravity, path: Path | None = None, title: str = "Probes", settled: bool = False
) -> Path | None:
    """probes.png: probe displacement along gravity against time, the level on a second axis.
    settled: the rows are settled states (quasi-static), drawn as points, not as a motion."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with open(out / "probes.csv") as f:
        header = f.readline().strip().split(",")
    data = np.loadtxt(out / "probes.csv", delimiter=",", skiprows=1, ndmin=2)
    names = [h[:-2] for h in header if h.endswith("_x") and not h.endswith("_mean_x")]
    names += [h[:-2] for h in header if h.endswith("_mean_x")]
    if not names:
        return None
    g = np.asarray(gravity, dtype=float)
    down = g / np.linalg.norm(g) if np.linalg.norm(g) > 0 else np.array([0.0, 0.0, -1.0])
    t = data[:, 0]
    beside = len(names) > LEGEND_INSIDE
    fig, ax = plt.subplots(figsize=(9.5 if beside else 6.5, 4.5))
    style = "o" if settled else "o-" if len(t) < 12 else "-"
    for name in names:
        u = np.stack([data[:, header.index(f"{name}_{c}")] for c in "xyz"], axis=1)
        ax.plot(t, u @ down * 1e3, style, label=name)
    ax.set_xlabel("time of the loads' schedule (s): settled states" if settled else "time (s)")
    ax.set_ylabel("displacement along gravity (mm)")
    ax.grid(True, alpha=0.3)
    level = data[:, header.index("level")]
    lines = ax.get_legend_handles_labels()[0]
    if np.isfinite(level).any():
        ax2 = ax.twinx()
        ax2.plot(t, level * 1e3, "s" if settled else "--", color="tab:gray", label="fluid level")
        ax2.set_ylabel("fluid level along up (mm)")
        lines += ax2.get_legend_handles_labels()[0]
    if beside:  # many probes: the legend beside the plot, in columns, covering nothing
        ax.legend(
            lines,
            [ln.get_label() for ln in lines],
            fontsize=7,
            loc="upper left",
            bbox_to_anchor=(1.12, 1.0),
            ncol=1 + len(lines) // 16,
            borderaxespad=0.0,
        )
    else:  # a few: in a row under the plot ("best" inside saw one axis only: it covered the level's line)
        ax.legend(
            lines,
            [ln.get_label() for ln in lines],
            fontsize=8,
            loc="upper center",
            bbox_to_anchor=(0.5, -0.16),
            ncol=min(len(lines), 4),
            frameon=False,
        )
    ax.set_title(title)
    fig.tight_layout()
    path = path or out / "probes.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def surface_error_plot(path, se) -> None:
    """compare.png: SIM - INTRA along the height axis over the ROI (the paper's Fig. 20), its
    axes named in RAS."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    err = np.array(se["error"], dtype=float) * 1e3
    ga, gb = np.array(se["grid_a"]) * 1e3, np.array(se["grid_b"]) * 1e3
    fig, ax = plt.subplots(figsize=(6, 4.5))
    im = ax.pcolormesh(
        ga, gb, err.T, shading="nearest", cmap="coolwarm", vmin=-np.nanmax(np.abs(err)), vmax=np.nanmax(np.abs(err))
    )
    fig.colorbar(im, ax=ax, label=f"SIM - INTRA along {se['height_axis']} (mm)")
    a, b = [axis for axis in "xyz" if axis != se["height_axis"]]
    anatomy = {"x": "x: R+ / L- (mm)", "y": "y: A+ / P- (mm)", "z": "z: S+ / I- (mm)"}  # RAS
    ax.set_xlabel(anatomy[a])
    ax.set_ylabel(anatomy[b])
    ax.set_aspect("equal")
    ax.set_title(f"Surface error seen along {se['height_axis']}: MAE {se['mae'] * 1e3:.2f} mm")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def pictures(out: Path) -> list[Path]:
    """Every picture of a finished run folder (rank 0 only)."""
    summary = json.loads((out / "summary.json").read_text())
    gravity = summary.get("gravity_vector", [0.0, 0.0, -9.81])
    title = f"{summary.get('scene', 'run')}: probes against time"
    made = [
        probe_plot(out, gravity, title=title, settled=summary.get("mode") == "quasi-static"),
        deformed_picture(out, gravity, summary.get("final_level_m"), anatomical=summary.get("frame") == "RAS"),
    ]
    return [p for p in made if p is not None]


def render_in_subprocess(out: Path) -> list[Path]:
    """pictures(out) in a fresh Python: VTK's OpenGL setup was seen to abort (std::bad_alloc)
    inside a process that had just run PETSc/MUMPS, and a crash there must not end a run
    whose results are already written. No MPI in the child."""
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if not k.startswith(("OMPI_", "PMIX_", "PMI_"))}
    for name in PICTURES:  # so that what exists afterwards was made now
        (out / name).unlink(missing_ok=True)
    proc = subprocess.run(
        [sys.executable, "-m", "fenics_brainshift.outputs.pictures", str(out)],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )
    made = [out / name for name in PICTURES if (out / name).is_file()]
    if proc.returncode != 0:
        log.warning(
            "pictures of %s failed (exit %d): %s",
            out,
            proc.returncode,
            (proc.stderr.strip().splitlines() or ["no message"])[-1],
        )
    return made


def main(argv: list[str] | None = None) -> int:
    import sys
    import warnings

    warnings.filterwarnings("ignore", module="pyvista")
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        raise SystemExit("usage: python -m fenics_brainshift.outputs.pictures RUN_FOLDER")
    pictures(Path(args[0]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
