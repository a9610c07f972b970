"""One client's conversation with the service: what each OpenIGTLink message it sends does to
its case, and the messages an update answers with. No sockets here (server.py has them), so
a recorded operation replays through the same code (record.py).

In: POINT (the point list, replaced whole: Slicer sends a markups list as one message each
time it changes), TRANSFORM or POSITION (a tracked pointer's tip: the latest kept; captured on
`capture`, or when it rests), POLYDATA (a surface scan), STRING commands (COMMANDS).
Out, after each update, in this order: the moved cortex (POLYDATA), the moved targets and
pre-operative points (POINT), the displacement and its uncertainty on a coarse grid (IMAGE),
the next point worth touching (POINT `NextPoint`), and the status (STRING JSON) last, so a
client knows the answer is complete. Everything in the client's frame (RAS, or LPS: x and y
negated) and millimetres, said in each message's metadata.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np

from .. import json_text
from ..errors import InputError
from . import igtl
from .case import Case

COMMANDS = ("update", "capture", "undo", "reset", "status")
REST_MM = 1.0  # a tip that stays within this ...
REST_S = 1.0  # ... for this long is captured once (it must then move REST_AWAY_MM before the next)
REST_AWAY_MM = 5.0
FLIP = np.array([-1.0, -1.0, 1.0])  # RAS <-> LPS


@dataclass
class Reply:
    """What handling a message asks for: an update, or messages to send now (encoded)."""

    update: bool = False
    send: list[bytes] = field(default_factory=list)
    log: str | None = None
    refused: bool = False  # the message was refused: an update asked before it is not made


class Session:
    def __init__(self, case: Case, frame: str = "RAS"):
        self.case, self.frame = case, frame
        self.tip: np.ndarray | None = None  # RAS m, the latest
        self._rest: tuple[np.ndarray, int, float] | None = None  # the resting tip's sum, samples, since when
        self._rested_at: np.ndarray | None = None
        self.updates = 0

    # -- in ----------------------------------------------------------------------------------

    def handle(self, message: igtl.Message, arrived: float | None = None) -> Reply:
        """What a decoded message does (arrived: when, by the service's clock: a tip's rest is
        timed by it, not by the client's stamps); an InputError's one line goes back as the status."""
        try:
            return self._handle(message, message.timestamp if arrived is None else arrived)
        except InputError as exc:
            said = str(exc).replace("--target: ", "the points: ")  # (the update's words are the command's)
            return Reply(
                send=[self._status({"error": said, **self.case.counts})],
                log=f"{message.type} {message.device!r}: {said}",
                refused=True,
            )

    def _handle(self, message: igtl.Message, arrived: float) -> Reply:
        kind, content = message.type, message.content
        if kind == "POINT":
            self.case.set_points(content.names, self._in(content.positions))
            return Reply(update=True)
        if kind == "POLYDATA":
            self.case.set_scan(self._in(content.points))
            return Reply(update=True)
        if kind in ("TRANSFORM", "POSITION"):
            position = content[:3, 3] if kind == "TRANSFORM" else content[0]
            tip = self._in(np.reshape(position, (1, 3)))[0]
            if not np.isfinite(tip).all():
                return Reply(log=f"{kind} {message.device!r}: the tip is not a number; ignored")
            self.tip = tip
            return self._rested(tip, arrived)
        if kind == "STRING":
            return self._command(content.strip(" \t\r\n\x00").lower())
        return Reply(log=f"{kind} {message.device!r}: not a message the service takes; ignored")

    def _command(self, command: str) -> Reply:
        if command == "update":
            return Reply(update=True)
        if command == "capture":
            if self.tip is None:
                raise InputError("capture: no pointer tip received yet (send its TRANSFORM or POSITION)")
            self.case.capture(self.tip)
            return Reply(update=True)
        if command == "undo":
            if not self.case.undo():
                return Reply(send=[self._status({"undo": "nothing to undo", **self.case.counts})])
            return Reply(update=True)
        if command == "reset":
            self.case.reset()
            return Reply(send=[self._status({"reset": True, **self.case.counts})])
        if command == "status":  # (the points held now; the last update's answer apart: it may be of others)
            last = self.case.last.status if self.case.last is not None else None
            return Reply(send=[self._status({**self.case.counts, "updates": self.updates, "last_update": last})])
        raise InputError(f"command {command[:40]!r}: not one of {', '.join(COMMANDS)}")

    def _rested(self, tip: np.ndarray, t: float) -> Reply:
        """A tip held still REST_S (within REST_MM of the mean of its samples since) is captured,
        once until it moves REST_AWAY_MM away."""
        if self._rested_at is not None and np.linalg.norm(tip - self._rested_at) * 1e3 < REST_AWAY_MM:
            return Reply()
        self._rested_at = None
        if self._rest is not None:
            total, count, since = self._rest
            if np.linalg.norm(tip - total / count) * 1e3 <= REST_MM:
                self._rest = (total + tip, count + 1, since)
                if t - since < REST_S:
                    return Reply()
                self._rest, self._rested_at = None, tip
                self.case.capture((total + tip) / (count + 1))
                return Reply(update=True, log=f"the tip rested {REST_S:g} s: captured as a touch")
        self._rest = (tip.copy(), 1, t)
        return Reply()

    def _in(self, positions) -> np.ndarray:
        """The client's mm (RAS or LPS) in RAS m."""
        xyz = np.asarray(positions, dtype=float).reshape(-1, 3) * 1e-3
        return xyz * FLIP if self.frame == "LPS" else xyz

    # -- out ---------------------------------------------------------------------------------

    def _out(self, positions: np.ndarray) -> np.ndarray:
        xyz = np.asarray(positions, dtype=float).reshape(-1, 3) * 1e3
        return xyz * FLIP if self.frame == "LPS" else xyz

    @property
    def metadata(self) -> dict[str, str]:
        return {"frame": self.frame, "units": "mm"}

    def _status(self, status: dict) -> bytes:
        return igtl.encode_string("BrainshiftStatus", json_text.dumps(status, indent=None), self.metadata)

    def answer(self) -> list[bytes]:
        """The update of the points held now, as the messages that carry it (status last); an
        update the points cannot make is answered by its one line as the status."""
        try:
            answer = self.case.update()
        except InputError as exc:
            return [self._status({"error": str(exc).replace("--target: ", "the points: "), **self.case.counts})]
        self.updates += 1
        meta, out = self.metadata, []
        if answer.surface is not None:
            points, triangles = answer.surface
            out.append(igtl.encode_polydata("BrainshiftCortex", self._out(points), triangles, meta))
        for name, (points, triangles) in answer.structures.items():
            out.append(igtl.encode_polydata(f"Brainshift{name}", self._out(points), triangles, meta))
        for device, (labels, points) in (("BrainshiftTargets", answer.targets), ("BrainshiftPre", answer.pre)):
            if len(labels):
                out.append(igtl.encode_point(device, labels, self._out(points), meta))
        if answer.displacement is not None:
            grid = self.case.grid
            matrix = grid.ijk_to_ras()
            shift = answer.displacement * 1e3
            if self.frame == "LPS":  # (the grid's axes and the vectors, both)
                matrix, shift = np.diag([-1.0, -1.0, 1.0, 1.0]) @ matrix, shift * FLIP
            # (i, j, k[, 3]) -> (k, j, i[, 3]): an IMAGE's voxels run with i fastest
            out.append(igtl.encode_image("BrainshiftShift", np.swapaxes(shift, 0, 2), matrix, meta, self.frame))
            spread = np.swapaxes(answer.spread * 1e3, 0, 2)
            out.append(igtl.encode_image("BrainshiftSpread", spread, matrix, meta, self.frame))
        if answer.suggestion is not None:
            out.append(igtl.encode_point("NextPoint", ["next"], self._out(answer.suggestion.position), meta))
        out.append(self._status(answer.status))
        return out


def status_of(messages: list[bytes]) -> dict:
    """The status JSON of an answer (its last message)."""
    header = igtl.parse_header(messages[-1][: igtl.HEADER_SIZE])
    return json.loads(igtl.decode(header, messages[-1][igtl.HEADER_SIZE :]).content)
