"""The paper's error measures recover a known synthetic shift exactly."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fenics_brainshift.cli import main
from fenics_brainshift.data import MESHES
from fenics_brainshift.outputs.metrics import compare, region
from fenics_brainshift.surfaces.files import read_surface

PRE = MESHES / "mni152_brain_surface.ply"
UP, SECOND = [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]


def _field(points):
    """A known, monotone shift (m): sag along -y growing towards anterior, plus a translation."""
    y0 = points[:, 1].min()
    return np.column_stack(
        [np.full(len(points), 0.001), -0.002 - 0.05 * (points[:, 1] - y0), np.full(len(points), 0.0005)]
    )


OFFSET = np.array([0.0, 0.0005, 0.0])  # the simulation's known error: 0.5 mm too far up


def test_known_shift_and_known_error_recovered_exactly():
    pre, _ = read_surface(PRE, 1e-3)
    shift = _field(pre)
    intra = pre + shift
    result = compare(
        pre, intra, intra + OFFSET, UP, SECOND, 0.005, 0.005, 0.010, roi=((-0.02, 0.02), (-0.02, 0.02)), spacing=0.001
    )
    for name in ("A", "B"):
        r = result[name]
        expected = shift[r["index_pre"]]
        np.testing.assert_allclose(r["d_mri"], expected, atol=1e-15)
        np.testing.assert_allclose(r["d_sim"], expected + OFFSET, atol=1e-15)
        # eq. 25 by hand: |(d_MRI - d_Sim) / d_MRI| per axis, and for the norms
        percent = [100 * abs(OFFSET[i] / expected[i]) for i in range(3)]
        norm = 100 * abs(np.linalg.norm(expected) - np.linalg.norm(expected + OFFSET)) / np.linalg.norm(expected)
        np.testing.assert_allclose(r["error_percent_vs_d_mri"], percent + [norm], rtol=1e-9, atol=1e-9)
    # node A is the most anterior PRE vertex, B the highest
    assert result["A"]["p_pre"][1] == pytest.approx(pre[:, 1].max())
    assert result["B"]["p_pre"][2] == pytest.approx(pre[:, 2].max())
    # the region centroids move by the mean shift of their points
    a = result["A"]["index_pre"]
    mask = region(pre, pre[a], UP, 0.005, 0.005)
    np.testing.assert_allclose(result["A"]["d_mri_bar"], shift[mask].mean(axis=0), atol=1e-12)
    se = result["surface_error"]  # SIM - INTRA heights along up: the offset, everywhere
    assert se["grid_points"] > 100
    for key in ("max", "min", "mean", "median", "mae"):
        assert se[key] == pytest.approx(OFFSET[1], abs=1e-12), key


def test_half_the_shift_is_fifty_percent_off():
    pre, _ = read_surface(PRE, 1e-3)
    shift = _field(pre)
    result = compare(pre, pre + shift, pre + 0.5 * shift, UP, SECOND, 0.005, 0.005, 0.010)
    errors = result["A"]["error_percent_vs_d_mri"]
    np.testing.assert_allclose(errors, [50.0, 50.0, 50.0, 50.0], rtol=1e-9)


def test_compare_command(tmp_path, capsys):
    import meshio

    pre, triangles = read_surface(PRE, 1.0)  # mm
    shift_mm = _field(pre * 1e-3) * 1e3
    meshio.Mesh(pre + shift_mm, [("triangle", triangles)]).write(tmp_path / "intra.stl")
    meshio.Mesh((pre + shift_mm) * 1e-3 + OFFSET, [("triangle", triangles)]).write(tmp_path / "sim.vtk")  # metres
    out = tmp_path / "c" / "compare.json"
    args = [
        "compare",
        str(PRE),
        str(tmp_path / "intra.stl"),
        str(tmp_path / "sim.vtk"),
        "--roi",
        "-20",
        "20",
        "-20",
        "20",
        "-o",
        str(out),
    ]
    assert main(args) == 0
    text = capsys.readouterr().out
    assert "node A" in text and "MAE 0.50 mm" in text
    data = json.loads(out.read_text())
    assert data["surface_error"]["mae"] == pytest.approx(OFFSET[1], abs=1e-7)  # float32 STL rounding
    assert Path(out.with_suffix(".png")).stat().st_size > 10_000
    assert main(["compare", str(PRE), str(PRE), str(tmp_path / "nope.vtk")]) == 2
    assert "not found" in capsys.readouterr().err
