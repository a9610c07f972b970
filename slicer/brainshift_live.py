"""3D Slicer's side of a live link to `brainshift serve` (OpenIGTLink).

Needs 3D Slicer 5 with the SlicerOpenIGTLink extension. Start the service first
(`brainshift serve ATLAS --port 18944`), load the pre-operative volume, then in Slicer's
Python console:

    exec(open(r"/path/to/fenics-brainshift/slicer/brainshift_live.py").read())

That connects to 127.0.0.1:18944 as a client and sends the point list "Touches" (created if
missing) whenever it changes. Then:

    send_command("update")   # also "capture", "undo", "reset", "status"
    live = start(host="10.0.0.5", port=18944, pre_volume="MRHead", points="Touches",
                 pointer="PointerToReference")   # other settings: replaces the link
    live.stop()

(or put this folder on sys.path, `import brainshift_live` and call `brainshift_live.start()`).

After each answer (its STRING `BrainshiftStatus` comes last) the script prints one status
line, puts the pre-operative volume under the grid transform "BrainshiftGrid" made from the
IMAGE `BrainshiftShift` (above any transform it has already; shown as it is now, not hardened:
take it out of the transform to see it as it was), overlays the IMAGE `BrainshiftSpread` (mm)
in colour in the slice views and colours the suggested next point `NextPoint` magenta. The
moved cortex (`BrainshiftCortex`) and points (`BrainshiftTargets`, `BrainshiftPre`) arrive
moved already and stay where they are.

Only the functions that say so need Slicer; they import it when called, so the rest (the
status line, the grid's geometry, the LPS/RAS flip) is plain Python, tested outside Slicer
(tests/test_slicer_live_script.py).
"""

from __future__ import annotations

import json
import sys

import numpy as np

HOST, PORT = "127.0.0.1", 18944
CONNECTOR = "BrainshiftConnector"
POINTS = "Touches"  # the point list sent to the service
COMMAND_NODE = "BrainshiftCommand"  # the text node whose text goes out as a STRING command
COMMANDS = ("update", "capture", "reset", "undo", "status")
# the nodes the connector makes of the service's messages, by device name
STATUS, SHIFT, SPREAD = "BrainshiftStatus", "BrainshiftShift", "BrainshiftSpread"
CORTEX, NEXT = "BrainshiftCortex", "NextPoint"
GRID_NODE = "BrainshiftGrid"
SPREAD_COLORS = "vtkMRMLColorTableNodeFileViridis.txt"
SPREAD_OPACITY = 0.4
NEXT_COLOR = (1.0, 0.0, 1.0)  # magenta: the service sends its points yellow
LPS_TO_RAS = np.diag([-1.0, -1.0, 1.0, 1.0])

_LIVE = globals().get("_LIVE")  # kept when the script is exec'd again, so start() stops the old link


# -- plain Python: no Slicer, no VTK ---------------------------------------------------------------


def frame_of(value) -> str:
    """The frame an incoming node's metadata names ("OpenIGTLink.frame"); RAS when it names none."""
    frame = "RAS" if value in (None, "") else str(value).strip().upper()
    if frame not in ("RAS", "LPS"):
        raise ValueError(f"frame {value!r}: expected RAS or LPS")
    return frame


def ijk_to_ras(ijk_to_frame, frame: str) -> np.ndarray:
    """An image's index-to-world matrix in RAS. Slicer takes an IMAGE's matrix as IJK-to-RAS; a
    server told LPS negated its first two rows (x and y), so they are negated back."""
    matrix = np.asarray(ijk_to_frame, dtype=float).reshape(4, 4)
    return LPS_TO_RAS @ matrix if frame_of(frame) == "LPS" else matrix


def displacement_to_ras(vectors, frame: str) -> np.ndarray:
    """Displacement vectors (..., 3) in RAS: x and y negated if they came in LPS."""
    vectors = np.asarray(vectors)
    if frame_of(frame) == "RAS":
        return vectors
    return vectors * np.array([-1.0, -1.0, 1.0], dtype=vectors.dtype)


def grid_geometry(ijk_to_ras_matrix, tolerance: float = 1e-6) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(origin (3,), spacing (3,), direction (4, 4)) of an IJK-to-RAS matrix: the spacing is each
    axis column's length, the direction its unit column (a grid transform needs orthonormal
    axes, so a sheared matrix is refused)."""
    matrix = np.asarray(ijk_to_ras_matrix, dtype=float)
    if matrix.shape != (4, 4) or not np.isfinite(matrix).all():
        raise ValueError(f"IJK-to-RAS: a finite 4x4 matrix, not {matrix.shape}")
    axes = matrix[:3, :3]
    spacing = np.linalg.norm(axes, axis=0)
    if (spacing <= 0).any():
        raise ValueError(f"IJK-to-RAS: an axis of length 0 (spacing {spacing.tolist()})")
    direction = np.eye(4)
    direction[:3, :3] = axes / spacing
    if not np.allclose(direction[:3, :3].T @ direction[:3, :3], np.eye(3), atol=tolerance):
        raise ValueError("IJK-to-RAS: the grid's axes are not perpendicular")
    return matrix[:3, 3].copy(), spacing, direction


def _mm(value) -> str:
    if value is None:
        return "n/a"
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return f"{value:.2f} mm"
    return str(value)


def status_line(text) -> str:
    """One line for the console from the service's status JSON."""
    try:
        status = json.loads(text)
    except (TypeError, ValueError):
        status = None
    if not isinstance(status, dict):
        return f"brainshift: the status is not a JSON object: {str(text)[:80]!r}"
    if status.get("error"):
        return f"brainshift: ERROR: {status['error']}"
    if "residual_mm" not in status:  # not an update's answer (a reset's, an undo's): as it is
        return "brainshift: " + "; ".join(f"{key}: {value}" for key, value in status.items())
    points = status.get("points", "?")
    parts = [
        f"{points} point{'' if points == 1 else 's'}",
        f"residual {_mm(status.get('residual_mm'))}",
        f"leave-one-out {_mm(status.get('leave_one_out_mm'))}",
    ]
    suggestion = status.get("suggestion")
    if isinstance(suggestion, dict):
        parts.append(
            f"next: touch {suggestion.get('label', NEXT)} (targets' spread {_mm(suggestion.get('spread_mm'))}"
            f" -> {_mm(suggestion.get('expected_spread_mm'))})"
        )
    if status.get("set_aside"):
        parts.append("set aside: " + ", ".join(str(label) for label in status["set_aside"]))
    warning = status.get("warning")
    if warning:
        parts.append("WARNING: " + ("; ".join(map(str, warning)) if isinstance(warning, list) else str(warning)))
    if status.get("atlas_id"):
        parts.append(f"atlas {status['atlas_id']}")
    return "brainshift: " + "; ".join(parts)


# -- Slicer: each function imports what it needs -----------------------------------------------------


def _find(name: str, class_name: str):
    import slicer

    return slicer.mrmlScene.GetFirstNode(name, class_name)


def _get_or_add(name: str, class_name: str):
    import slicer

    node = _find(name, class_name)
    return node if node is not None else slicer.mrmlScene.AddNewNodeByClass(class_name, name)


def connect(host: str = HOST, port: int = PORT, name: str = CONNECTOR):
    """The OpenIGTLinkIF connector node `name` (reused, or added), set as a client of host:port;
    not started yet (open_link starts it once its outgoing nodes are registered)."""
    connector = _get_or_add(name, "vtkMRMLIGTLConnectorNode")
    if connector.GetState() != connector.StateOff:
        connector.Stop()  # a new host or port takes effect at the next Start
    connector.SetTypeClient(host, int(port))
    return connector


def open_link(host: str = HOST, port: int = PORT, points: str = POINTS, pointer: str | None = None):
    """(connector, point list, command node): a started client connector whose outgoing nodes are
    the point list (sent whole, as one POINT message, each time a point is added or moved; and
    again on every reconnection), the command text node and, if named, a tracked pointer's
    linear transform node (TRANSFORM)."""
    connector = connect(host, port)
    touches = _get_or_add(points, "vtkMRMLMarkupsFiducialNode")
    touches.SetAttribute("OpenIGTLinkIF.pushOnConnect", "true")
    connector.RegisterOutgoingMRMLNode(touches)
    commands = _get_or_add(COMMAND_NODE, "vtkMRMLTextNode")
    connector.RegisterOutgoingMRMLNode(commands)
    if pointer:
        tip = _find(pointer, "vtkMRMLLinearTransformNode")  # only linear transform nodes go out as TRANSFORM
        if tip is None:
            print(f"brainshift: no linear transform node {pointer!r}: the pointer is not sent")
        else:
            connector.RegisterOutgoingMRMLNode(tip)
    connector.Start()
    return connector, touches, commands


def push_command(connector, node, text: str) -> None:
    """Send `text` as a STRING from the outgoing text node: the connector sends it by itself when
    the text changes (it observes TextModifiedEvent), but the same text again changes nothing, so
    then it is pushed explicitly."""
    if node.GetText() == text:
        connector.PushNode(node)
    else:
        node.SetText(text)


def grid_transform(shift, frame: str = "RAS", name: str = GRID_NODE):
    """The grid transform node `name` (reused, or added) made from the displacement volume `shift`.

    Convention: a node placed under a transform has it applied "to parent", i.e. from the node's
    own coordinates to the parent's (Slicer's modeling convention; the "from parent" slot holds the
    resampling direction: Docs/developer_guide/modules/transforms.md). The pre-operative volume's
    own coordinates are pre-operative positions X, and the service's u is given at X: X moves to
    X + u(X). So the displacement is set as the transform to parent, X -> X + u(X), and each
    pre-operative voxel is drawn where its tissue is now. To draw the volume Slicer needs the
    inverse (world -> X), which vtkOrientedGridTransform finds by Newton iterations as it goes;
    points and models under it take the forward map. The "from parent" slot would need u at
    intra-operative positions, which the service does not send.
    """
    import vtk
    from vtk.util import numpy_support

    import slicer

    matrix = vtk.vtkMatrix4x4()
    shift.GetIJKToRASMatrix(matrix)
    origin, spacing, direction = grid_geometry(ijk_to_ras(slicer.util.arrayFromVTKMatrix(matrix), frame))
    # the volume node keeps its whole geometry in IJK-to-RAS (its image's origin 0, spacing 1: the
    # connector resets them on every message); a grid transform reads the origin and spacing from
    # its image and the axes from GridDirectionMatrix. A copy: the connector rewrites its image.
    grid = vtk.vtkImageData()
    grid.DeepCopy(shift.GetImageData())
    grid.SetOrigin(*origin)
    grid.SetSpacing(*spacing)
    vectors = numpy_support.vtk_to_numpy(grid.GetPointData().GetScalars())  # a view, (points, 3)
    vectors[:] = displacement_to_ras(vectors, frame)
    grid.GetPointData().GetScalars().Modified()
    transform = slicer.vtkOrientedGridTransform()
    transform.SetGridDirectionMatrix(slicer.util.vtkMatrixFromArray(direction))
    transform.SetDisplacementGridData(grid)
    node = _get_or_add(name, "vtkMRMLGridTransformNode")
    node.SetAndObserveTransformToParent(transform)
    return node


def show_spread(spread, transform, background=None, set_layers: bool = True) -> None:
    """The spread volume in colour, 0 (outside the brain) transparent, under the same transform as
    the pre-operative volume (its values belong to pre-operative positions too); made the slice
    views' foreground at SPREAD_OPACITY over `background` when `set_layers`."""
    import slicer

    spread.SetAndObserveTransformNodeID(transform.GetID() if transform is not None else None)
    display = spread.GetDisplayNode()
    if display is None:
        spread.CreateDefaultDisplayNodes()
        display = spread.GetDisplayNode()
    high = max(spread.GetImageData().GetScalarRange()[1], 0.1)
    display.SetAndObserveColorNodeID(SPREAD_COLORS)
    display.AutoWindowLevelOff()
    display.SetWindowLevelMinMax(0.0, high)
    display.AutoThresholdOff()
    display.SetThreshold(1e-3, high + 1.0)
    display.ApplyThresholdOn()
    if set_layers:
        slicer.util.setSliceViewerLayers(
            background=background if background is not None else "keep-current",
            foreground=spread,
            foregroundOpacity=SPREAD_OPACITY,
        )


def style_next_point(node) -> None:
    """NextPoint large and magenta, locked. Again after every answer: the connector sets a point
    list's colour from each POINT message's colours."""
    display = node.GetDisplayNode()
    if display is None:
        node.CreateDefaultDisplayNodes()
        display = node.GetDisplayNode()
    display.SetSelectedColor(*NEXT_COLOR)
    display.SetColor(*NEXT_COLOR)
    display.SetGlyphTypeFromString("StarBurst2D")
    display.SetGlyphScale(5.0)
    node.SetLocked(True)


def place_under(node, transform) -> None:
    """`node` under `transform`, not hardened. A transform chain the node has already (a
    registration, say) is kept and the transform goes at its top: the service's positions are
    world positions, so its displacement applies after the chain (and to all it carries)."""
    top = node
    while top.GetParentTransformNode() is not None:
        if top.GetParentTransformNode().GetID() == transform.GetID():
            return  # there already
        top = top.GetParentTransformNode()
    top.SetAndObserveTransformNodeID(transform.GetID())


def _pre_operative_volume(choice):
    """The volume named (or given); else the first scalar volume that is not a label map nor ours."""
    import slicer

    if choice is not None and not isinstance(choice, str):
        return choice
    if choice:
        return _find(choice, "vtkMRMLScalarVolumeNode")
    for node in slicer.util.getNodesByClass("vtkMRMLScalarVolumeNode"):
        if not node.IsA("vtkMRMLLabelMapVolumeNode") and not (node.GetName() or "").startswith("Brainshift"):
            return node
    return None


class Live:
    """The link: its connector and outgoing nodes, and the observers that show each answer."""

    def __init__(self, host=HOST, port=PORT, pre_volume=None, points=POINTS, pointer=None):
        import slicer

        self.connector, self.touches, self.commands = open_link(host, port, points, pointer)
        self.pre_choice, self.pre_volume = pre_volume, None
        self._observers, self._status, self._scheduled = [], None, False
        self._shift_stamp, self._layers_set, self._warned_lps = None, False, False
        self._observe(slicer.mrmlScene, slicer.vtkMRMLScene.NodeAddedEvent, self._watch)
        # the connector sends the list on PointModifiedEvent (a point added or moved), not on removal
        self._observe(self.touches, slicer.vtkMRMLMarkupsNode.PointRemovedEvent, self._push_points)
        for event in (self.connector.ConnectedEvent, self.connector.DisconnectedEvent):
            self._observe(self.connector, event, self._connection)
        self._watch()
        print(f"brainshift: connecting to {host}:{port}; the point list {points!r} goes to the service")

    def _observe(self, obj, event, callback) -> None:
        self._observers.append((obj, obj.AddObserver(event, callback)))

    def stop(self) -> None:
        """Remove the observers and stop the connector (the nodes stay)."""
        for obj, tag in self._observers:
            obj.RemoveObserver(tag)
        self._observers = []
        self.connector.Stop()

    def send(self, text: str) -> bool:
        text = text.strip().lower()
        if text not in COMMANDS:
            raise ValueError(f"command {text!r}: one of {', '.join(COMMANDS)}")
        if self.connector.GetState() != self.connector.StateConnected:
            print(f"brainshift: not connected; {text!r} not sent")
            return False
        push_command(self.connector, self.commands, text)
        return True

    def _connection(self, caller, event) -> None:
        state = "connected" if caller.GetState() == caller.StateConnected else "disconnected (retrying)"
        print(f"brainshift: {state}")

    def _push_points(self, caller, event) -> None:
        self.connector.PushNode(self.touches)

    def _watch(self, caller=None, event=None) -> None:
        """Observe the status text node once it exists (the connector adds it at the first answer)."""
        if self._status is None:
            self._status = _find(STATUS, "vtkMRMLTextNode")
            if self._status is not None:
                import vtk

                self._observe(self._status, vtk.vtkCommand.ModifiedEvent, self._answered)

    def _answered(self, caller, event) -> None:
        # The status is the answer's last message, but the connector imports the messages of one
        # poll by device, not in arrival order: show the answer once this poll is over.
        if not self._scheduled:
            import qt

            self._scheduled = True
            qt.QTimer.singleShot(0, self._show)

    def _show(self) -> None:
        self._scheduled = False
        print(status_line(self._status.GetText()))
        transform = None
        shift = _find(SHIFT, "vtkMRMLVectorVolumeNode")
        if shift is not None and shift.GetImageData() is not None:
            frame = frame_of(shift.GetAttribute("OpenIGTLink.frame"))
            if frame == "LPS" and not self._warned_lps:
                self._warned_lps = True
                print(
                    "brainshift: the service sends LPS; the grid is turned to RAS here, but models, points "
                    "and the spread arrive mirrored and Slicer sends RAS: run `brainshift serve` in RAS for Slicer"
                )
            stamp = (shift.GetMTime(), shift.GetImageData().GetMTime())
            if stamp != self._shift_stamp:  # a status alone (no new shift) keeps the transform
                grid_transform(shift, frame)
                self._shift_stamp = stamp
            transform = _find(GRID_NODE, "vtkMRMLGridTransformNode")
        if self.pre_volume is None:
            self.pre_volume = _pre_operative_volume(self.pre_choice)
            if self.pre_volume is not None:
                print(f"brainshift: the pre-operative volume is {self.pre_volume.GetName()!r}")
        if self.pre_volume is not None and transform is not None:
            place_under(self.pre_volume, transform)
        spread = _find(SPREAD, "vtkMRMLScalarVolumeNode")
        if spread is not None and spread.GetImageData() is not None:
            show_spread(spread, transform, self.pre_volume, set_layers=not self._layers_set)
            self._layers_set = True
        next_point = _find(NEXT, "vtkMRMLMarkupsFiducialNode")
        if next_point is not None:
            style_next_point(next_point)
        cortex = _find(CORTEX, "vtkMRMLModelNode")
        if cortex is not None and cortex.GetDisplayNode() is not None:
            cortex.GetDisplayNode().SetVisibility2D(True)  # its outline in the slice views too


def start(host: str = HOST, port: int = PORT, pre_volume=None, points: str = POINTS, pointer: str | None = None):
    """Open the link (stopping one opened before) and return it. pre_volume: a volume node or its
    name (default: the first scalar volume); points: the point list's name; pointer: a tracked
    pointer's linear transform node's name, sent as TRANSFORM."""
    global _LIVE
    if _LIVE is not None:
        _LIVE.stop()
    _LIVE = Live(host, port, pre_volume, points, pointer)
    return _LIVE


def send_command(text: str) -> bool:
    """Send one of COMMANDS to the service (after start())."""
    if _LIVE is None:
        raise RuntimeError("no link: run start() first")
    return _LIVE.send(text)


def _in_slicer() -> bool:
    return hasattr(sys.modules.get("slicer"), "mrmlScene")


if __name__ == "__main__":  # exec(open(...).read()) in Slicer's console, or run by a plain Python
    if _in_slicer():
        start()
    else:
        print("brainshift_live.py runs in 3D Slicer's Python console: exec(open(r'PATH').read())")
