"""slicer/brainshift_live.py outside 3D Slicer: it parses, imports without Slicer (its Slicer
calls import Slicer lazily), its plain functions against hand-worked values, and its Slicer
functions against small stand-ins that record the calls made (the order of the calls, not
Slicer's behaviour). The grid transform is also built on real VTK image data where VTK is
installed, with a plain vtkGridTransform standing in for Slicer's oriented one."""

from __future__ import annotations

import ast
import importlib.util
import json
import runpy
import sys
import types

import numpy as np
import pytest

from conftest import ROOT

pytestmark = pytest.mark.usefixtures("serial_only")

SCRIPT = ROOT / "slicer" / "brainshift_live.py"


def load(monkeypatch, slicer=None):
    """The script as a fresh module; `slicer` stands in for Slicer's module (None: none at all)."""
    monkeypatch.setitem(sys.modules, "slicer", slicer)
    spec = importlib.util.spec_from_file_location("brainshift_live_under_test", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_script_parses():
    # as Python 3.9 too: the Python of Slicer 5.0 to 5.8
    tree = ast.parse(SCRIPT.read_text(), filename=str(SCRIPT), feature_version=(3, 9))
    assert "exec(open(" in ast.get_docstring(tree)  # the docstring says how to run it in Slicer


def test_it_imports_without_slicer_vtk_or_qt(monkeypatch):
    monkeypatch.setitem(sys.modules, "vtk", None)  # None in sys.modules: importing it raises
    monkeypatch.setitem(sys.modules, "qt", None)
    module = load(monkeypatch, slicer=None)
    assert module._LIVE is None and not module._in_slicer()  # nothing started
    assert module.frame_of(None) == "RAS"
    with pytest.raises(RuntimeError, match="start"):
        module.send_command("update")


def test_run_by_a_plain_python_it_says_where_to_run_it(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "slicer", None)
    namespace = runpy.run_path(str(SCRIPT), run_name="__main__")
    assert "Slicer's Python console" in capsys.readouterr().out and namespace["_LIVE"] is None


@pytest.fixture
def live(monkeypatch):
    return load(monkeypatch)


# -- the plain functions -------------------------------------------------------------------------------


def _rotation(degrees_z: float, degrees_x: float) -> np.ndarray:
    a, b = np.radians(degrees_z), np.radians(degrees_x)
    rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    rx = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    return rz @ rx


def test_grid_geometry_gives_back_spacing_direction_and_origin(live):
    rotation = _rotation(30.0, -50.0)
    matrix = np.eye(4)
    matrix[:3, :3] = rotation @ np.diag([2.0, 3.0, 4.0])
    matrix[:3, 3] = [10.0, -20.0, 30.0]
    origin, spacing, direction = live.grid_geometry(matrix)
    assert np.allclose(spacing, [2.0, 3.0, 4.0])
    assert np.allclose(origin, [10.0, -20.0, 30.0])
    assert np.allclose(direction[:3, :3], rotation) and np.allclose(direction[3], [0, 0, 0, 1])
    assert np.allclose(direction[:3, 3], 0.0)
    # and back: index (1, 2, 3) by the pieces is the matrix's point
    index = np.array([1.0, 2.0, 3.0])
    assert np.allclose(origin + direction[:3, :3] @ (spacing * index), (matrix @ [*index, 1.0])[:3])


def test_grid_geometry_refuses_a_sheared_or_flat_grid(live):
    sheared = np.eye(4)
    sheared[0, 1] = 0.5
    with pytest.raises(ValueError, match="perpendicular"):
        live.grid_geometry(sheared)
    with pytest.raises(ValueError, match="length 0"):
        live.grid_geometry(np.diag([1.0, 0.0, 1.0, 1.0]))
    with pytest.raises(ValueError, match="4x4"):
        live.grid_geometry(np.eye(3))


def test_lps_to_ras_negates_x_and_y_of_the_vectors_and_of_the_grid(live):
    u = np.array([[1.0, 2.0, 3.0], [-4.0, 5.0, -6.0]], dtype=np.float32)
    ras = live.displacement_to_ras(u, "LPS")
    assert np.array_equal(ras, [[-1.0, -2.0, 3.0], [4.0, -5.0, -6.0]]) and ras.dtype == np.float32
    assert live.displacement_to_ras(u, "ras") is u  # RAS: as it came
    assert live.displacement_to_ras(u, None) is u  # no metadata: RAS
    # the server in LPS negates the rows x and y of its IJK-to-RAS matrix: undone here
    m_ras = np.eye(4)
    m_ras[:3, :3] = _rotation(20.0, 10.0) * [2.0, 3.0, 4.0]
    m_ras[:3, 3] = [10.0, -20.0, 30.0]
    m_lps = np.diag([-1.0, -1.0, 1.0, 1.0]) @ m_ras
    assert np.allclose(live.ijk_to_ras(m_lps, "LPS"), m_ras)
    assert np.allclose(live.ijk_to_ras(m_ras, "RAS"), m_ras)
    with pytest.raises(ValueError, match="RAS or LPS"):
        live.frame_of("XYZ")


def test_the_status_line(live):
    status = {
        "atlas_id": "a1b2",
        "points": 6,
        "residual_mm": 0.8412,
        "leave_one_out_mm": 1.2,
        "warning": "two points disagree",
        "suggestion": {"label": "NextPoint", "expected_spread_mm": 1.3, "spread_mm": 2.1},
        "set_aside": ["P3"],
    }
    assert live.status_line(json.dumps(status)) == (
        "brainshift: 6 points; residual 0.84 mm; leave-one-out 1.20 mm; next: touch NextPoint "
        "(targets' spread 2.10 mm -> 1.30 mm); set aside: P3; WARNING: two points disagree; atlas a1b2"
    )
    bare = {"points": 1, "residual_mm": None, "leave_one_out_mm": None, "warning": None, "suggestion": None}
    assert live.status_line(json.dumps(bare)) == "brainshift: 1 point; residual n/a; leave-one-out n/a"
    assert live.status_line('{"error": "no points yet", "points": 0}') == "brainshift: ERROR: no points yet"
    warnings = live.status_line('{"points": 2, "residual_mm": 0.5, "warning": ["a", "b"]}')
    assert warnings.endswith("WARNING: a; b")
    reset = live.status_line('{"reset": true, "pairs": 0, "touches": 0}')  # not an update's answer
    assert reset == "brainshift: reset: True; pairs: 0; touches: 0"
    for text in ("", "not json", "[1, 2]", None):  # a text node's text is "" before any answer
        assert live.status_line(text).startswith("brainshift: the status is not a JSON object")


# -- the Slicer functions, against stand-ins -------------------------------------------------------------


class FakeNode:
    def __init__(self, log, class_name, name):
        self.log, self.class_name, self.name, self.text, self.attributes = log, class_name, name, "", {}

    def GetName(self):
        return self.name

    def GetID(self):
        return f"{self.class_name}_{self.name}"

    def SetAttribute(self, key, value):
        self.attributes[key] = value
        self.log.append(("SetAttribute", self.name, key, value))

    def GetText(self):
        return self.text

    def SetText(self, text):
        self.text = text
        self.log.append(("SetText", self.name, text))


class FakeConnector(FakeNode):
    StateOff, StateWaitConnection, StateConnected = 0, 1, 2
    ConnectedEvent, DisconnectedEvent = 118944, 118945

    def __init__(self, log, class_name, name, state=0):
        super().__init__(log, class_name, name)
        self.state = state

    def GetState(self):
        return self.state

    def Stop(self):
        self.log.append(("Stop",))

    def SetTypeClient(self, host, port):
        self.log.append(("SetTypeClient", host, port))

    def RegisterOutgoingMRMLNode(self, node):
        self.log.append(("RegisterOutgoingMRMLNode", node.name))

    def Start(self):
        self.log.append(("Start",))

    def PushNode(self, node):
        self.log.append(("PushNode", node.name))


class FakeScene:
    def __init__(self, log, nodes=(), kinds=None):
        self.log, self.nodes = log, {(node.class_name, node.name): node for node in nodes}
        self.kinds = {"vtkMRMLIGTLConnectorNode": FakeConnector, **(kinds or {})}

    def GetFirstNode(self, name, class_name):
        return self.nodes.get((class_name, name))

    def AddNewNodeByClass(self, class_name, name):
        self.log.append(("AddNewNodeByClass", class_name, name))
        node = self.kinds.get(class_name, FakeNode)(self.log, class_name, name)
        self.nodes[(class_name, name)] = node
        return node


def fake_slicer(scene, **more):
    return types.SimpleNamespace(mrmlScene=scene, util=types.SimpleNamespace(), **more)


def test_open_link_makes_a_client_registers_the_point_list_then_starts(monkeypatch):
    log = []
    live = load(monkeypatch, fake_slicer(FakeScene(log)))
    connector, touches, commands = live.open_link("10.1.2.3", "18945")
    assert log == [
        ("AddNewNodeByClass", "vtkMRMLIGTLConnectorNode", "BrainshiftConnector"),
        ("SetTypeClient", "10.1.2.3", 18945),
        ("AddNewNodeByClass", "vtkMRMLMarkupsFiducialNode", "Touches"),
        ("SetAttribute", "Touches", "OpenIGTLinkIF.pushOnConnect", "true"),
        ("RegisterOutgoingMRMLNode", "Touches"),
        ("AddNewNodeByClass", "vtkMRMLTextNode", "BrainshiftCommand"),
        ("RegisterOutgoingMRMLNode", "BrainshiftCommand"),
        ("Start",),
    ]
    assert (touches.class_name, commands.class_name) == ("vtkMRMLMarkupsFiducialNode", "vtkMRMLTextNode")


def test_open_link_reuses_a_running_connector_and_the_nodes_and_sends_the_pointer(monkeypatch, capsys):
    log = []
    running = FakeConnector(log, "vtkMRMLIGTLConnectorNode", "BrainshiftConnector", state=2)
    mine = FakeNode(log, "vtkMRMLMarkupsFiducialNode", "Mine")
    pointer = FakeNode(log, "vtkMRMLLinearTransformNode", "PointerToReference")
    live = load(monkeypatch, fake_slicer(FakeScene(log, [running, mine, pointer])))
    connector, touches, _ = live.open_link(port=18944, points="Mine", pointer="PointerToReference")
    assert connector is running and touches is mine
    assert log[:2] == [("Stop",), ("SetTypeClient", "127.0.0.1", 18944)]  # stopped, then the new address
    registered = [entry[1] for entry in log if entry[0] == "RegisterOutgoingMRMLNode"]
    assert registered == ["Mine", "BrainshiftCommand", "PointerToReference"] and log[-1] == ("Start",)
    log.clear()
    live.open_link(points="Mine", pointer="NoSuchPointer")
    assert "NoSuchPointer" in capsys.readouterr().out
    assert [entry[1] for entry in log if entry[0] == "RegisterOutgoingMRMLNode"] == ["Mine", "BrainshiftCommand"]


def test_a_command_goes_out_once_even_when_it_repeats(monkeypatch):
    log = []
    live = load(monkeypatch, fake_slicer(FakeScene(log)))
    connector = FakeConnector(log, "vtkMRMLIGTLConnectorNode", "c", state=FakeConnector.StateConnected)
    text = FakeNode(log, "vtkMRMLTextNode", "BrainshiftCommand")
    link = live.Live.__new__(live.Live)  # its parts only: no observers
    link.connector, link.commands = connector, text
    assert link.send(" Update ") and link.send("update") and link.send("undo")
    # a new text: set (the connector pushes on TextModifiedEvent); the same text: pushed here
    assert log == [
        ("SetText", "BrainshiftCommand", "update"),
        ("PushNode", "BrainshiftCommand"),
        ("SetText", "BrainshiftCommand", "undo"),
    ]
    with pytest.raises(ValueError, match="update"):
        link.send("solve")
    connector.state = FakeConnector.StateWaitConnection
    log.clear()
    assert not link.send("status") and log == []


# -- the grid transform, on real VTK image data -------------------------------------------------------------

SHAPE = (3, 4, 5)  # i, j, k
A = np.array([[0.05, -0.02, 0.01], [0.03, 0.04, -0.02], [-0.01, 0.02, 0.06]])
B = np.array([1.0, -2.0, 0.5])


def displacement(x):
    """Affine in x, so the grid's trilinear interpolation reproduces it between the nodes."""
    return x @ A.T + B


@pytest.fixture
def vtk_live(monkeypatch):
    vtk = pytest.importorskip("vtk")
    log = []

    class GridNode(FakeNode):
        def SetAndObserveTransformToParent(self, transform):
            self.to_parent = transform
            self.log.append(("SetAndObserveTransformToParent", self.name))

    class OrientedGrid(vtk.vtkGridTransform):  # VTK's grid transform, recording its axes
        def SetGridDirectionMatrix(self, matrix):
            self.direction = np.array([[matrix.GetElement(r, c) for c in range(4)] for r in range(4)])

    def vtk_matrix_from_array(array):
        matrix = vtk.vtkMatrix4x4()
        for r in range(4):
            for c in range(4):
                matrix.SetElement(r, c, float(array[r][c]))
        return matrix

    util = types.SimpleNamespace(
        arrayFromVTKMatrix=lambda m: np.array([[m.GetElement(r, c) for c in range(4)] for r in range(4)]),
        vtkMatrixFromArray=vtk_matrix_from_array,
    )
    scene = FakeScene(log, kinds={"vtkMRMLGridTransformNode": GridNode})
    slicer = types.SimpleNamespace(mrmlScene=scene, util=util, vtkOrientedGridTransform=OrientedGrid)
    return load(monkeypatch, slicer), vtk, log


class FakeVolume:
    """What the connector makes of an IMAGE: the geometry in IJK-to-RAS, the image at 0 with spacing 1."""

    def __init__(self, vtk, ijk_to_ras, vectors):
        self.matrix, self.image = ijk_to_ras, vtk.vtkImageData()
        self.image.SetDimensions(*SHAPE)
        self.image.AllocateScalars(vtk.VTK_FLOAT, 3)
        from vtk.util import numpy_support

        numpy_support.vtk_to_numpy(self.image.GetPointData().GetScalars())[:] = vectors

    def GetIJKToRASMatrix(self, matrix):
        for r in range(4):
            for c in range(4):
                matrix.SetElement(r, c, self.matrix[r, c])

    def GetImageData(self):
        return self.image


def _grid_points(matrix):
    """The RAS point of each voxel, in VTK's order (i fastest)."""
    k, j, i = np.meshgrid(*(np.arange(n) for n in SHAPE[::-1]), indexing="ij")
    index = np.stack([i.ravel(), j.ravel(), k.ravel(), np.ones(i.size)], axis=1)
    return (index @ matrix.T)[:, :3]


def test_the_grid_transform_moves_x_to_x_plus_u_in_ras_from_either_frame(vtk_live):
    live, vtk, log = vtk_live
    from vtk.util import numpy_support

    m_ras = np.diag([2.0, 3.0, 4.0, 1.0])
    m_ras[:3, 3] = [10.0, -20.0, 30.0]
    u_ras = displacement(_grid_points(m_ras))
    shift = FakeVolume(vtk, m_ras, u_ras)
    node = live.grid_transform(shift, "RAS")
    transform = node.to_parent
    grid = transform.GetDisplacementGrid()
    assert log[-1] == ("SetAndObserveTransformToParent", "BrainshiftGrid")
    assert np.allclose(grid.GetOrigin(), [10.0, -20.0, 30.0]) and np.allclose(grid.GetSpacing(), [2.0, 3.0, 4.0])
    assert np.allclose(transform.direction, np.eye(4))
    assert shift.image.GetOrigin() == (0.0, 0.0, 0.0) and shift.image.GetSpacing() == (1.0, 1.0, 1.0)  # a copy
    x = np.array([10.0, -20.0, 30.0]) + [2.0 * 0.5, 3.0 * 1.5, 4.0 * 2.25]  # between the nodes
    assert np.allclose(transform.TransformPoint(*x), x + displacement(x), atol=1e-4)  # to parent: X -> X + u(X)
    assert np.allclose(transform.GetInverse().TransformPoint(*(x + displacement(x))), x, atol=1e-3)

    # the same field as a server told LPS sends it: the matrix's rows x, y and the vectors' x, y negated
    flip = np.diag([-1.0, -1.0, 1.0, 1.0])
    lps = live.grid_transform(FakeVolume(vtk, flip @ m_ras, u_ras * [-1.0, -1.0, 1.0]), "LPS").to_parent
    lps_grid = lps.GetDisplacementGrid()
    assert np.allclose(lps_grid.GetOrigin(), grid.GetOrigin()) and np.allclose(lps_grid.GetSpacing(), grid.GetSpacing())
    assert np.allclose(lps.direction, np.eye(4))
    vectors = numpy_support.vtk_to_numpy(lps_grid.GetPointData().GetScalars())
    assert np.allclose(vectors, u_ras, atol=1e-5)
    assert np.allclose(lps.TransformPoint(*x), x + displacement(x), atol=1e-4)


class FakeTransformable(FakeNode):
    def __init__(self, log, class_name, name, parent=None):
        super().__init__(log, class_name, name)
        self.parent = parent

    def GetParentTransformNode(self):
        return self.parent

    def SetAndObserveTransformNodeID(self, node_id):
        self.log.append(("SetAndObserveTransformNodeID", self.name, node_id))


def test_the_grid_goes_above_a_transform_chain_the_volume_has(live):
    log = []
    grid = FakeTransformable(log, "vtkMRMLGridTransformNode", "BrainshiftGrid")
    registration = FakeTransformable(log, "vtkMRMLLinearTransformNode", "Registration")
    pre = FakeTransformable(log, "vtkMRMLScalarVolumeNode", "MRHead", parent=registration)
    live.place_under(pre, grid)  # volume -> registration -> grid: the registration is kept
    assert log == [("SetAndObserveTransformNodeID", "Registration", grid.GetID())]
    registration.parent = grid
    live.place_under(pre, grid)  # there already: nothing to do
    plain = FakeTransformable(log, "vtkMRMLScalarVolumeNode", "CT")
    live.place_under(plain, grid)
    assert log[1:] == [("SetAndObserveTransformNodeID", "CT", grid.GetID())]
