"""Pictures a surgeon reads: checked on the figure objects, not on pixels. The
facts are the run's own files (probes.csv, summary.json) and hand-picked numbers."""

from __future__ import annotations

import json

import matplotlib
import numpy as np
import pytest

from fenics_brainshift.outputs import pictures

matplotlib.use("Agg")


@pytest.fixture
def figures(monkeypatch):
    """The matplotlib figures the plots save, kept open for inspection."""
    from matplotlib.figure import Figure

    saved = []
    original = Figure.savefig

    def keep(self, *args, **kwargs):
        saved.append(self)
        self.canvas.draw()  # (layout done: the boxes below are final)
        return original(self, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", keep)
    monkeypatch.setattr("matplotlib.pyplot.close", lambda *a, **k: None)
    return saved


@pytest.mark.parametrize(
    "value, top", [(1.9737, 2.0), (7.01, 10.0), (2.5, 2.5), (0.0123, 0.02), (20.75, 25.0), (0.0, 1.0)]
)
def test_a_colour_bar_runs_from_zero_to_a_round_number(value, top):
    assert pictures.nice_ceiling(value) == pytest.approx(top)


def _probes_folder(tmp_path, names, times):
    header = ["t", "level"] + [f"{n}_{c}" for n in names for c in "xyz"]
    rows = [
        [t, 0.02] + [(-1e-3 * (i + 1) * t if c == "z" else 0.0) for i in range(len(names)) for c in "xyz"]
        for t in times
    ]
    np.savetxt(tmp_path / "probes.csv", np.array(rows), delimiter=",", header=",".join(header), comments="")
    return tmp_path


def test_many_probes_are_named_beside_the_plot_and_settled_states_are_points(tmp_path, figures):
    """With 20 markups the legend covered the plot and its title; three settled states were
    joined by lines as if the shift grew linearly in time; the title cited the paper."""
    names = [f"F-{i}" for i in range(20)]
    pictures.probe_plot(
        _probes_folder(tmp_path, names, [0.0, 10.0, 16.0]), [0, 0, -9.81], title="my scene: probes", settled=True
    )
    fig = figures[-1]
    ax = fig.axes[0]
    legend = ax.get_legend().get_window_extent()
    assert not legend.overlaps(ax.get_window_extent())  # beside the axes, covering nothing
    assert all(line.get_linestyle() == "None" and line.get_marker() == "o" for line in ax.get_lines())
    assert "settled states" in ax.get_xlabel()
    assert ax.get_title() == "my scene: probes" and "paper" not in ax.get_title()


def test_a_dynamic_run_draws_its_probes_as_lines(tmp_path, figures):
    """A few probes: their legend (loc "best" inside the probes' axes, blind to the level's
    second axis) covered the fluid level's line; now it is under the plot, covering nothing."""
    pictures.probe_plot(_probes_folder(tmp_path, ["a", "b"], np.linspace(0.0, 2.0, 21)), [0, 0, -9.81])
    ax = figures[-1].axes[0]
    assert all(line.get_linestyle() == "-" for line in ax.get_lines()[:2]) and ax.get_xlabel() == "time (s)"
    legend = ax.get_legend().get_window_extent()
    assert not legend.overlaps(ax.get_window_extent())
    assert not any(legend.overlaps(t.get_window_extent()) for t in [ax.xaxis.label, *ax.get_xticklabels()])


def test_the_surface_error_map_names_its_axes_in_ras(tmp_path, figures):
    """compare.png had no axis labels or orientation."""
    grid = np.linspace(-0.02, 0.02, 5)
    se = {
        "error": np.zeros((5, 5)).tolist(),
        "grid_a": grid.tolist(),
        "grid_b": grid.tolist(),
        "height_axis": "y",
        "mae": 0.0005,
    }
    pictures.surface_error_plot(tmp_path / "compare.png", se)
    ax = figures[-1].axes[0]
    assert ax.get_xlabel() == "x: R+ / L- (mm)" and ax.get_ylabel() == "z: S+ / I- (mm)"
    assert "paper" not in ax.get_title()


SPY = """
import json, sys
import pyvista as pv
from fenics_brainshift.outputs import pictures
calls = {"clim": [], "points": 0, "skull": 0}
add_mesh, add_points = pv.Plotter.add_mesh, pv.Plotter.add_points
def mesh(self, *args, **kwargs):
    if kwargs.get("scalars") == "displacement (mm)":
        calls["clim"].append(list(kwargs["clim"]))
    calls["skull"] += kwargs.get("style") == "wireframe"
    return add_mesh(self, *args, **kwargs)
def points(self, *args, **kwargs):
    calls["points"] += 1
    return add_points(self, *args, **kwargs)
pv.Plotter.add_mesh, pv.Plotter.add_points = mesh, points
pictures.pictures(__import__("pathlib").Path(sys.argv[1]))
print(json.dumps(calls))
"""


def test_the_deformed_picture_starts_its_colour_bar_at_zero_and_draws_the_probes(tmp_path, serial_only):
    """The cube's colour bar started at 2.33e-18; the landmarks and the skull were not drawn
    (the skull is now written beside the run, for Slicer too). (Rendered in a
    fresh process, as runs do: VTK's OpenGL aborts in a process that has run PETSc.)"""
    import subprocess
    import sys

    from fenics_brainshift import load_scene, run

    from conftest import subprocess_env

    pytest.importorskip("pyvista")
    import meshio

    # a closed box skull around the cube (0.05 x 0.05 x 0.025 m) with a floor 2 mm below it
    lo, hi = np.array([-0.01, -0.01, -0.002]), np.array([0.06, 0.06, 0.04])
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    quads = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    box = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])
    meshio.write(str(tmp_path / "skull.stl"), meshio.Mesh(corners, [("triangle", box)]))
    out = tmp_path / "out"
    run(
        load_scene(
            "cube",
            [
                "mesh.cells=[4, 4, 2]",
                "time.mode=quasi-static",
                "output.pictures=false",
                f"skull.file='{tmp_path / 'skull.stl'}'",
            ],
        ),
        out,
    )
    from fenics_brainshift.surfaces.files import read_surface

    written, _ = read_surface(out / "skull.stl", 1e-3)  # the skull the run used, mm RAS for Slicer
    np.testing.assert_allclose(written.min(axis=0), lo, atol=1e-6)
    np.testing.assert_allclose(written.max(axis=0), hi, atol=1e-6)
    env = {k: v for k, v in subprocess_env().items() if not k.startswith(("OMPI_", "PMIX_", "PMI_"))}
    done = subprocess.run([sys.executable, "-c", SPY, str(out)], capture_output=True, text=True, env=env, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    calls = json.loads(done.stdout.strip().splitlines()[-1])
    top = 1e3 * json.loads((out / "summary.json").read_text())["max_displacement_m"]
    assert calls["clim"] and calls["clim"][0][0] == 0.0 and top <= calls["clim"][0][1] <= 2.5 * top
    assert calls["points"] == 1  # the cube's probes (probes_final.mrk.json), in red
    assert calls["skull"] == 1  # and the skull, as a cage
