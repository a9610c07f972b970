"""`brainshift serve` over a real TCP socket on loopback, with pyigtl's client as a navigation
system would connect (and a raw socket where pyigtl cannot: POLYDATA, the order of an
answer, bad bytes): what goes in, what comes out in each frame, bad traffic, the record and
its replay. Answers are checked against the atlas's update called directly on the same
points, and against interpolation of its displacement done here."""

from __future__ import annotations

import json
import socket
import struct
import sys
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pyigtl
import pytest
from mpi4py import MPI

from fenics_brainshift import load_scene
from fenics_brainshift.atlas import store
from fenics_brainshift.atlas.build import build
from fenics_brainshift.atlas.locate import MeshLocator
from fenics_brainshift.atlas.scenarios import parse_vary
from fenics_brainshift.atlas.update import update
from fenics_brainshift.cli import main as brainshift
from fenics_brainshift.commands.serve import resume, session_factory
from fenics_brainshift.errors import InputError
from fenics_brainshift.images import write_markups
from fenics_brainshift.images.targets import Target
from fenics_brainshift.theatre import igtl, server
from fenics_brainshift.theatre.record import Recorder, read_messages

from conftest import mpirun, run_group, subprocess_env

pytestmark = pytest.mark.usefixtures("serial_only")

VARY = ["fluid.level=0.02,0.03,0.04", "gravity.angle_z=-8,0,8"]


@pytest.fixture(scope="module")
def atlas_folder(tmp_path_factory):
    built, _ = build(
        load_scene("brain", ["mesh.voxel=0.01", "time.mode=quasi-static"]), parse_vary(VARY), MPI.COMM_WORLD
    )
    folder = tmp_path_factory.mktemp("serve") / "atlas"
    store.write(folder, built)
    return folder


@pytest.fixture(scope="module")
def atlas(atlas_folder):
    return store.read(atlas_folder)


def _args(folder, **extra):
    base = dict(
        atlas=str(folder),
        pre=None,
        targets=None,
        frame="RAS",
        noise=1.0,
        grid=4.0,
        share=False,
        record=None,
        structure=[],
    )
    return SimpleNamespace(**{**base, **extra})


class Served:
    """A server on a free loopback port, its loop in a thread under the test's control."""

    def __init__(self, args, record: Path | None = None, allow=None):
        self.log: list[str] = []
        make, options = session_factory(args)
        self.recorder, resumed = None, (None, None)
        if record is not None:  # (as `brainshift serve --record` starts)
            resumed = resume(record, make, options)
            self.recorder = Recorder(record, options, resumed[0])
        self.server = server.Server(lambda: make(resumed[1]), "127.0.0.1", 0, allow, self.recorder, log=self.log.append)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self.server.serve, args=(self.stop.is_set, 0.01), daemon=True)
        self.thread.start()

    def close(self):
        self.stop.set()
        self.thread.join(10)


@pytest.fixture()
def served(atlas_folder):
    s = Served(_args(atlas_folder))
    yield s
    s.close()


def _touches(atlas, count=12, seed=0, weights=(0.0, 0.6, 0.4)):
    """Points on the cortex moved by a mix of modes (RAS m), and that displacement."""
    c = np.zeros(len(atlas.scenarios))
    c[[1, 4, 7][: len(weights)]] = weights
    moved = atlas.surface_points + np.tensordot(c, atlas.surface_modes.astype(float), axes=1)
    top = np.flatnonzero(moved[:, 1] > np.percentile(moved[:, 1], 90))
    picked = np.random.default_rng(seed).choice(top, count, replace=False)
    return _wire(moved[picked])


def _wire(points: np.ndarray) -> np.ndarray:
    """Points (m) as they arrive: millimetres in float32 (OpenIGTLink's POINT)."""
    return (points * 1e3).astype(np.float32).astype(float) * 1e-3


class Raw:
    """A client on a plain socket: sends bytes, reads whole messages (framing read here by hand;
    bodies decoded by the codec, an IMAGE's kept as bytes: the service never takes one)."""

    def __init__(self, port):
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=20)
        self.buffer = b""

    def send(self, data: bytes):
        self.sock.sendall(data)

    def _take(self, size: int) -> bytes:
        while len(self.buffer) < size:
            data = self.sock.recv(1 << 20)
            if not data:
                raise ConnectionError("closed by the server")
            self.buffer += data
        out, self.buffer = self.buffer[:size], self.buffer[size:]
        return out

    def message(self) -> igtl.Message:
        head = self._take(58)
        version, kind, device, seconds, fraction, size, crc = struct.unpack(">H12s20sIIQQ", head)
        body = self._take(size)
        kind, device = kind.rstrip(b"\0").decode(), device.rstrip(b"\0").decode()
        assert igtl.CRC64(body) == crc
        if kind == "IMAGE":  # (read by pyigtl, from the bytes as they came)
            image = pyigtl.ImageMessage()
            image.unpack(pyigtl.MessageBase.parse_header(head), body)
            return igtl.Message(kind, device, seconds, {}, image)
        return igtl.decode(igtl.Header(version, kind, device, seconds, size, crc), body)

    def answer(self) -> list[igtl.Message]:
        """Messages up to and including the next BrainshiftStatus."""
        out = [self.message()]
        while out[-1].device != "BrainshiftStatus":
            out.append(self.message())
        return out

    def closed(self, within: float = 5.0) -> bool:
        self.sock.settimeout(within)
        try:
            while self.sock.recv(1 << 20):
                pass
            return True
        except (ConnectionResetError, BrokenPipeError):
            return True
        except TimeoutError:
            return False

    def close(self):
        self.sock.close()


def _wait(client, device, timeout=20.0):
    message = client.wait_for_message(device, timeout=timeout)
    assert message is not None, f"no {device} within {timeout} s"
    return message


def test_points_in_the_updated_brain_out_through_pyigtl(served, atlas):
    touches = _touches(atlas)
    labels = [f"t{i}" for i in range(len(touches))]
    direct = update(atlas, Target(touches, None, labels), 1e-3)
    client = pyigtl.OpenIGTLinkClient("127.0.0.1", served.server.port)
    try:
        client.send_message(pyigtl.PointMessage(positions=touches * 1e3, names=labels, device_name="Touches"))
        status = json.loads(_wait(client, "BrainshiftStatus").string)
        targets = _wait(client, "BrainshiftTargets")
        shift = _wait(client, "BrainshiftShift")
        spread = _wait(client, "BrainshiftSpread")
        nxt = _wait(client, "NextPoint")
    finally:
        client.stop()
    assert status["kind"] == "point-to-surface" and status["points"] == 12
    rms = lambda r: float(np.sqrt(np.mean(r**2))) * 1e3  # noqa: E731
    assert status["residual_mm"] == pytest.approx(rms(direct.residual), abs=1e-9)
    assert status["prior_residual_mm"] == pytest.approx(rms(direct.prior_residual), abs=1e-9)
    assert np.allclose(status["weights"], direct.weights, atol=1e-12)
    # the moved targets (the atlas's probes) by interpolation here, mm
    probes = atlas.info["probes"]
    names = list(probes)
    points = np.array([probes[k] for k in names])
    index, weight, _ = MeshLocator(atlas.points, atlas.tetrahedra).weights(points)
    moved = (points + np.einsum("nj,njd->nd", weight, direct.displacement[index])) * 1e3
    assert list(targets.names) == names
    assert np.allclose(np.asarray(targets.positions), moved, atol=1e-3)  # (float32 on the wire)
    # the displacement image: at voxels inside the brain, the displacement interpolated there
    data = np.asarray(shift.image, dtype=float)  # (k, j, i, 3) as pyigtl reads it
    assert data.ndim == 4 and data.shape[-1] == 3
    matrix = np.asarray(shift.ijk_to_world_matrix, dtype=float)
    k, j, i = np.argwhere(np.linalg.norm(data, axis=-1) > 0.5 * np.linalg.norm(data, axis=-1).max())[:20].T
    ras = (matrix @ np.c_[i, j, k, np.ones(len(i))].T).T[:, :3] * 1e-3
    index, weight, outside = MeshLocator(atlas.points, atlas.tetrahedra).weights(ras)
    assert np.all(outside == 0)
    expected = np.einsum("nj,njd->nd", weight, direct.displacement[index]) * 1e3
    assert np.allclose(data[k, j, i], expected, atol=1e-4)
    assert np.asarray(spread.image).max() > 0
    # the suggestion: a point of the cortex, said to lower the targets' spread
    assert status["suggestion"]["expected_spread_mm"] < status["suggestion"]["spread_mm"]
    assert np.asarray(nxt.positions).shape == (1, 3)


def test_an_answer_ends_with_its_status_and_carries_the_moved_cortex(served, atlas):
    touches = _touches(atlas, seed=1)
    labels = [f"t{i}" for i in range(len(touches))]
    direct = update(atlas, Target(touches, None, labels), 1e-3)
    raw = Raw(served.server.port)
    try:
        raw.send(igtl.encode_point("Touches", labels, touches * 1e3))
        answer = raw.answer()
    finally:
        raw.close()
    devices = [m.device for m in answer]
    assert devices[-1] == "BrainshiftStatus" and devices.count("BrainshiftStatus") == 1
    assert set(devices) >= {"BrainshiftCortex", "BrainshiftTargets", "BrainshiftShift", "BrainshiftSpread", "NextPoint"}
    cortex = answer[devices.index("BrainshiftCortex")]
    assert cortex.metadata == {"frame": "RAS", "units": "mm"}
    assert np.array_equal(cortex.content.triangles, atlas.surface_triangles)
    assert np.allclose(cortex.content.points, (atlas.surface_points + direct.surface_displacement) * 1e3, atol=1e-3)


def test_an_lps_client_gets_the_same_update_in_lps(atlas_folder, atlas):
    touches = _touches(atlas, seed=2)
    labels = [f"t{i}" for i in range(len(touches))]
    direct = update(atlas, Target(touches, None, labels), 1e-3)
    s = Served(_args(atlas_folder, frame="LPS"))
    raw = Raw(s.server.port)
    try:
        raw.send(igtl.encode_point("Touches", labels, touches * 1e3 * [-1, -1, 1]))
        answer = {m.device: m for m in raw.answer()}
    finally:
        raw.close()
        s.close()
    status = json.loads(answer["BrainshiftStatus"].content)
    assert np.allclose(status["weights"], direct.weights, atol=1e-12)
    cortex = answer["BrainshiftCortex"]
    assert cortex.metadata["frame"] == "LPS" and answer["BrainshiftShift"].content.world_coordinate_system == "lps"
    assert np.allclose(
        cortex.content.points, (atlas.surface_points + direct.surface_displacement) * 1e3 * [-1, -1, 1], atol=1e-3
    )


def test_labels_among_the_pre_operative_points_are_pairs_and_the_rest_touches(atlas_folder, atlas, tmp_path):
    top = np.flatnonzero(atlas.points[:, 1] > np.percentile(atlas.points[:, 1], 90))[:3]
    pre = atlas.points[top]
    write_markups(tmp_path / "pre.mrk.json", ["A", "B", "C"], pre * 1e3)
    c = np.zeros(len(atlas.scenarios))
    c[4] = 1.0
    u = np.tensordot(c, atlas.vertex_modes[:].astype(float), axes=1)
    touches = _touches(atlas, count=4, seed=3, weights=(0.0, 1.0))
    measured = _wire(np.vstack([pre + u[top], touches]))
    labels = ["A", "B", "C", "s1", "s2", "s3", "s4"]
    s = Served(_args(atlas_folder, pre=str(tmp_path / "pre.mrk.json")))
    raw = Raw(s.server.port)
    try:
        raw.send(igtl.encode_point("Touches", labels, measured * 1e3))
        answer = {m.device: m for m in raw.answer()}
    finally:
        raw.close()
        s.close()
    status = json.loads(answer["BrainshiftStatus"].content)
    assert status["kind"] == "point-to-point and point-to-surface"
    assert (status["pairs"], status["surface"]) == (3, 4)
    pre = (pre * 1e3).astype(np.float32).astype(float) * 1e-3  # (read back from the markups file's mm)
    direct = update(atlas, Target(measured, np.vstack([pre, np.full((4, 3), np.nan)]), labels), 1e-3)
    assert np.allclose(status["weights"], direct.weights, atol=1e-12)
    assert list(answer["BrainshiftPre"].content.names) == ["A", "B", "C"]


def test_a_tracked_tip_is_captured_and_the_commands_do_what_they_say(served, atlas):
    touches = _touches(atlas, count=6, seed=4)
    raw = Raw(served.server.port)
    try:
        for k, tip in enumerate(touches):
            matrix = np.eye(4)
            matrix[:3, 3] = tip * 1e3
            raw.send(igtl.encode_transform("PointerToTracker", matrix))
            raw.send(igtl.encode_string("cmd", "capture"))
            status = json.loads(raw.answer()[-1].content)
            if k < 4:  # (too few touches for an update: said, not fitted)
                assert "too few" in status["error"] and status["touches"] == k + 1
        assert status["touches"] == 6 and status["kind"] == "point-to-surface"
        raw.send(igtl.encode_string("cmd", "undo"))
        assert json.loads(raw.answer()[-1].content)["touches"] == 5
        raw.send(igtl.encode_string("cmd", "status"))
        said = json.loads(raw.answer()[-1].content)
        assert said["touches"] == 5 and said["updates"] >= 2 and said["last_update"]["touches"] == 5
        raw.send(igtl.encode_string("cmd", "reset"))
        assert json.loads(raw.answer()[-1].content) == {
            "reset": True,
            "pairs": 0,
            "surface": 0,
            "touches": 0,
            "scan": 0,
        }
        raw.send(igtl.encode_string("cmd", "dance"))
        assert "not one of update, capture, undo, reset, status" in json.loads(raw.answer()[-1].content)["error"]
    finally:
        raw.close()


def test_a_tip_held_still_is_captured_once_by_the_services_clock(served, atlas):
    """A tip within 1 mm of where it rests for 1 s is one touch (its samples jittering by
    0.4 mm a coordinate, its stamps all the same: the service's clock times the rest); held
    again 3 mm away, no second; 8 mm away, a second."""
    tip = _touches(atlas, count=1, seed=5)[0] * 1e3
    rng = np.random.default_rng(0)
    raw = Raw(served.server.port)

    def rest(at, seconds=1.3):
        for _ in range(int(seconds * 60)):
            message = bytearray(igtl.encode_position("Tip", at + rng.uniform(-0.4, 0.4, 3)))
            message[34:42] = bytes(8)  # (the client's stamp: always the same)
            message[50:58] = struct.pack(">Q", igtl.CRC64(bytes(message[58:])))
            raw.send(bytes(message))
            time.sleep(1 / 60)
        raw.send(igtl.encode_string("cmd", "status"))
        while "last_update" not in (status := json.loads(raw.answer()[-1].content)):
            pass  # (a capture's own answer first: too few touches to fit)
        return status["touches"]

    try:
        assert rest(tip) == 1
        assert rest(tip + [3.0, 0.0, 0.0]) == 1
        assert rest(tip + [8.0, 0.0, 0.0]) == 2
    finally:
        raw.close()


def test_a_surface_scan_is_fitted_point_to_surface(served, atlas):
    scan = _touches(atlas, count=300, seed=6)
    raw = Raw(served.server.port)
    try:
        raw.send(igtl.encode_polydata("Scan", scan * 1e3, np.array([[0, 1, 2]])))
        status = json.loads(raw.answer()[-1].content)
    finally:
        raw.close()
    assert status["scan"] == 300 and status["kind"] == "point-to-surface"
    assert status["residual_mm"] < 0.05 < status["prior_residual_mm"]


def _frame(kind: bytes, body: bytes, size: int | None = None, crc: int | None = None) -> bytes:
    return (
        struct.pack(
            ">H12s20sIIQQ",
            2,
            kind,
            b"bad",
            0,
            0,
            len(body) if size is None else size,
            igtl.CRC64(body) if crc is None else crc,
        )
        + body
    )


def test_bad_traffic_is_dropped_and_every_other_client_served(served, atlas):
    touches = _touches(atlas, seed=7)
    labels = [f"t{i}" for i in range(len(touches))]
    good = Raw(served.server.port)
    try:
        # a wrong CRC: that message dropped, its client kept
        bad = bytearray(igtl.encode_point("Touches", labels, touches * 1e3))
        bad[-1] ^= 0xFF
        good.send(bytes(bad))
        good.send(igtl.encode_point("Touches", labels, touches * 1e3))
        assert json.loads(good.answer()[-1].content)["points"] == 12
        # a NaN point, and points of another frame: one line back, nothing fitted
        nan = touches.copy() * 1e3
        nan[3, 1] = np.nan
        good.send(igtl.encode_point("Touches", labels, nan))
        assert "'t3' is not a number" in json.loads(good.answer()[-1].content)["error"]
        good.send(igtl.encode_point("Touches", labels, touches * 1e3 + [0, 0, 400]))
        assert "outside the atlas's brain" in json.loads(good.answer()[-1].content)["error"]
        for name, data in (
            ("an unknown type", _frame(b"VIDEO", b"x" * 10)),
            ("a body over its limit", _frame(b"POLYDATA", b"", size=1 << 40)),
            ("garbage", b"\x00\xff" * 64),
        ):
            other = Raw(served.server.port)
            other.send(data)
            assert other.closed(), name
            other.close()
        cut = Raw(served.server.port)  # a header cut off, then gone
        cut.send(igtl.encode_point("Touches", labels, touches * 1e3)[:30])
        cut.close()
        good.send(igtl.encode_string("cmd", "update"))
        assert json.loads(good.answer()[-1].content)["points"] == 12  # still served, its last good list
    finally:
        good.close()
    lines = "\n".join(served.log)
    assert "fails its CRC-64 check" in lines and "unsupported type 'VIDEO'" in lines
    assert "over the" in lines and "disconnected mid-message" in lines


def test_a_flood_costs_one_update_a_turn_and_two_clients_get_their_own(served, atlas):
    first, second = _touches(atlas, seed=8), _touches(atlas, seed=9, weights=(0.0, 0.0, 1.0))
    labels = [f"t{i}" for i in range(12)]
    a, b = Raw(served.server.port), Raw(served.server.port)
    try:
        a.send(igtl.encode_point("Touches", labels, first * 1e3))
        b.send(igtl.encode_point("Touches", labels, second * 1e3))
        wa, wb = (json.loads(c.answer()[-1].content)["weights"] for c in (a, b))
        assert np.allclose(wa, update(atlas, Target(first, None, labels), 1e-3).weights, atol=1e-12)
        assert np.allclose(wb, update(atlas, Target(second, None, labels), 1e-3).weights, atol=1e-12)
        before = served.server.updates
        started = time.perf_counter()
        a.send(igtl.encode_string("cmd", "update") * 10_000)
        answers = 0
        a.sock.settimeout(3.0)
        try:
            while True:
                answers += sum(m.device == "BrainshiftStatus" for m in a.answer())
        except TimeoutError:
            pass
        assert 1 <= answers < 1000 and served.server.updates - before == answers
        assert time.perf_counter() - started < 60
        b.send(igtl.encode_string("cmd", "update"))
        assert np.allclose(json.loads(b.answer()[-1].content)["weights"], wb, atol=1e-12)
    finally:
        a.close()
        b.close()


def test_a_client_that_never_reads_is_closed_and_the_others_served(served, atlas, monkeypatch):
    monkeypatch.setattr(server, "MAX_OUTBOX", 4 << 20)
    touches = _touches(atlas, seed=10)
    labels = [f"t{i}" for i in range(12)]
    deaf = socket.create_connection(("127.0.0.1", served.server.port))
    deaf.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    try:
        for _ in range(40):
            deaf.sendall(igtl.encode_point("Touches", labels, touches * 1e3))
            time.sleep(0.05)
    except OSError:
        pass  # (closed by the server)
    finally:
        deaf.close()
    deadline = time.time() + 20
    while not any("answers not read" in line for line in served.log) and time.time() < deadline:
        time.sleep(0.1)
    assert any("answers not read" in line for line in served.log)
    raw = Raw(served.server.port)
    try:
        raw.send(igtl.encode_point("Touches", labels, touches * 1e3))
        assert json.loads(raw.answer()[-1].content)["points"] == 12
    finally:
        raw.close()


def _play(served: Served, atlas, steps) -> list[dict]:
    """Each step on a new or the same connection: ("points", client, n) or ("command", client, text)."""
    touches = _touches(atlas, count=24, seed=11)
    clients, statuses = {}, []
    try:
        for kind, who, what in steps:
            raw = clients.get(who) or clients.setdefault(who, Raw(served.server.port))
            if kind == "points":
                raw.send(
                    igtl.encode_point(
                        "Touches", [f"t{i}" for i in range(what)], touches[who % 4 : who % 4 + what] * 1e3
                    )
                )
            else:
                raw.send(igtl.encode_string("cmd", what))
            statuses.append(json.loads(raw.answer()[-1].content))
    finally:
        for raw in clients.values():
            raw.close()
    return statuses


def test_a_recorded_operation_replays_and_resumes_across_kills(atlas_folder, atlas, tmp_path, capsys):
    record = tmp_path / "record"
    first = Served(_args(atlas_folder), record=record)
    done = _play(first, atlas, [("points", 0, 8), ("points", 1, 11), ("points", 0, 12), ("command", 1, "undo")])
    first.close()  # (its recorder left open, as a killed service leaves it) ...
    with open(record / "messages.bin", "ab") as f:  # ... a record half-written by the kill
        f.write(b"BSR1" + b"\x00" * 26)
    # a second start cuts the half-written record off and resumes the case of the client whose
    # good update came last (client 2's, undone back to none: then client 1's 12 points)
    second = Served(_args(atlas_folder), record=record)
    again = _play(second, atlas, [("command", 5, "update"), ("points", 6, 9)])
    second.close()
    assert done[-1]["error"] and again[0]["points"] == 12 and again[1]["points"] == 9
    assert len(read_messages(record)) == 6
    assert brainshift(["replay", str(record), "--atlas", str(atlas_folder)]) == 0
    assert "6 messages from 4 client(s) over 2 start(s), 6 updates: each the recorded answer" in capsys.readouterr().out
    with pytest.raises(InputError, match="served with frame 'RAS', not 'LPS'"):  # (a record replays with one set)
        Served(_args(atlas_folder, frame="LPS"), record=record)
    # the record damaged, edited, or replayed with other options: one line each
    assert brainshift(["replay", str(record), "--atlas", str(atlas_folder), "--frame", "LPS"]) == 2
    assert "served with --frame 'RAS', not 'LPS'" in capsys.readouterr().err
    lines = (record / "updates.jsonl").read_text().splitlines()
    changed = json.loads(lines[0])
    changed["status"]["weights"][1] += 1e-3
    for text, words in (
        ("\n".join([json.dumps(changed)] + lines[1:]) + "\n", "update 1 of 6 differs from the record"),
        ("\n".join(lines[:2] + ['{"foo": 1}'] + lines[2:]) + "\n", "updates.jsonl is damaged at line 3"),
        ("\n".join(lines[:2] + ["[1, 2]"]) + "\n", "updates.jsonl is damaged at line 3"),
    ):
        (record / "updates.jsonl").write_text(text)
        assert brainshift(["replay", str(record), "--atlas", str(atlas_folder)]) == 2
        assert words in capsys.readouterr().err
    (record / "updates.jsonl").write_text("\n".join(lines) + "\n")
    data = (record / "messages.bin").read_bytes()
    (record / "messages.bin").write_bytes(data[:100] + b"x" + data[101:])
    assert brainshift(["replay", str(record), "--atlas", str(atlas_folder)]) == 2
    assert "messages.bin is damaged after byte" in capsys.readouterr().err


def test_a_shared_case_replays_in_the_order_the_service_met_its_messages(atlas_folder, atlas, tmp_path, capsys):
    record = tmp_path / "shared"
    s = Served(_args(atlas_folder, share=True), record=record)
    touches = _touches(atlas, count=14, seed=14)
    a, b = Raw(s.server.port), Raw(s.server.port)
    try:  # (A's and B's lists within one turn of the loop: one case, two answers)
        a.send(igtl.encode_point("Touches", [f"t{i}" for i in range(8)], touches[:8] * 1e3))
        b.send(igtl.encode_point("Touches", [f"t{i}" for i in range(12)], touches[:12] * 1e3))
        a.answer(), b.answer()
        a.send(igtl.encode_string("cmd", "update"))
        assert json.loads(a.answer()[-1].content)["points"] in (8, 12)
    finally:
        a.close(), b.close()
        s.close()
    assert brainshift(["replay", str(record), "--atlas", str(atlas_folder), "--share"]) == 0
    assert "each the recorded answer" in capsys.readouterr().out


def test_serve_binds_loopback_warns_off_it_and_refuses_clients_not_allowed(atlas_folder, capsys):
    assert brainshift(["serve", str(atlas_folder), "--port", "0", "--seconds", "0.5"]) == 0
    out = capsys.readouterr().err  # (the service's log)
    assert "on 127.0.0.1:" in out and "WARNING" not in out
    assert brainshift(["serve", str(atlas_folder), "--host", "0.0.0.0", "--port", "0", "--seconds", "0.5"]) == 0
    assert "OpenIGTLink has no authentication" in capsys.readouterr().err
    s = Served(_args(atlas_folder), allow=["10.9.8.7"])
    try:
        raw = Raw(s.server.port)
        assert raw.closed()
        raw.close()
        time.sleep(0.2)
        assert any("not among --allow" in line for line in s.log)
    finally:
        s.close()
    taken = socket.socket()
    taken.bind(("127.0.0.1", 0))
    taken.listen(1)
    try:
        port = taken.getsockname()[1]
        assert brainshift(["serve", str(atlas_folder), "--port", str(port), "--seconds", "0.5"]) == 2
        assert f"--port {port}" in capsys.readouterr().err
    finally:
        taken.close()
    assert brainshift(["serve", str(atlas_folder), "--port", "70000"]) == 2
    assert brainshift(["serve", str(Path(atlas_folder).parent / "none")]) == 2


def test_serve_starts_as_one_process_without_dolfinx_and_refuses_mpirun(atlas_folder):
    """The service as a user starts it: no DOLFINx, PETSc or MPI started (a third of its
    start-up was MPI's), and under mpirun every rank refuses in one line."""
    code = (
        "import sys\n"
        "from fenics_brainshift.cli import main\n"
        f"code = main(['serve', {str(atlas_folder)!r}, '--port', '0', '--seconds', '0.2'])\n"
        "loaded = [m for m in ('dolfinx', 'petsc4py', 'ufl', 'basix', 'mpi4py.MPI') if m in sys.modules]\n"
        "print('LOADED', loaded, code)\n"
    )
    done = run_group([sys.executable, "-c", code], 120, env=subprocess_env())
    assert "LOADED [] 0" in done.stdout, done.stdout + done.stderr
    done = run_group(mpirun() + [sys.executable, "-c", code], 120, env=subprocess_env())
    assert done.stdout.count("LOADED [] 2") == 2 and done.stderr.count("run it as one process") == 2


def test_a_growing_list_keeps_its_cross_validated_alpha_while_near_as_many_points(atlas):
    from fenics_brainshift.theatre.case import ALPHA_KEPT, ALPHA_MIN_POINTS, Case

    touches = _touches(atlas, count=16, seed=12)
    case = Case(atlas, grid=None)
    chosen = None
    for n in range(ALPHA_MIN_POINTS, 16):
        labels = [f"t{i}" for i in range(n)]
        case.set_points(labels, touches[:n])
        answer = case.update()
        target = Target(touches[:n], None, labels)
        if n == ALPHA_MIN_POINTS or n > (1 + ALPHA_KEPT) * ALPHA_MIN_POINTS:  # chosen again
            assert answer.status["alpha_from"] == "cross-validation"
            assert answer.result.alpha == update(atlas, target, 1e-3).alpha
            chosen = answer.result.alpha if n == ALPHA_MIN_POINTS else chosen
        else:
            assert answer.status["alpha_from"] == f"kept (cross-validated on {ALPHA_MIN_POINTS} points)"
            kept = update(atlas, target, 1e-3, alpha=chosen)
            assert answer.result.alpha == chosen and np.allclose(answer.result.weights, kept.weights, atol=1e-12)
        if n == ALPHA_MIN_POINTS + 3:
            break
    assert case.update(Target(touches[:11], None, [f"t{i}" for i in range(11)])).result.curve  # (a target given: anew)


def test_a_fault_in_one_update_is_logged_and_the_service_goes_on(served, atlas, monkeypatch):
    from fenics_brainshift.theatre.session import Session

    answer, calls = Session.answer, []

    def faulty(self):
        calls.append(1)
        if len(calls) == 1:
            raise RuntimeError("a fault")
        return answer(self)

    monkeypatch.setattr(Session, "answer", faulty)
    touches = _touches(atlas, seed=13)
    labels = [f"t{i}" for i in range(12)]
    raw = Raw(served.server.port)
    try:
        raw.send(igtl.encode_point("Touches", labels, touches * 1e3))
        time.sleep(1.0)
        raw.send(igtl.encode_string("cmd", "update"))
        assert json.loads(raw.answer()[-1].content)["points"] == 12
    finally:
        raw.close()
    assert any("the update failed: internal error RuntimeError('a fault')" in line for line in served.log)


def test_a_clients_flood_of_bad_messages_is_a_few_log_lines(served, atlas):
    raw = Raw(served.server.port)
    bad = bytearray(igtl.encode_string("cmd", "update"))
    bad[-1] ^= 0xFF
    try:
        raw.send(bytes(bad) * 500)
        raw.send(igtl.encode_string("cmd", "status"))
        raw.answer()
    finally:
        raw.close()
    deadline = time.time() + 10
    while not any("more such lines not shown" in line for line in served.log) and time.time() < deadline:
        time.sleep(0.05)
    crc = [line for line in served.log if "fails its CRC-64 check" in line]
    assert len(crc) == server.LOG_BURST
    assert any(f"{500 - server.LOG_BURST} more such lines not shown" in line for line in served.log)


def test_the_live_demo_plays_an_operation_against_the_service(atlas_folder, tmp_path):
    """demos/live.py against a real `brainshift serve` process: both plays answered touch by
    touch, the error read from the moved targets the service sent, the picture written."""
    out = tmp_path / "live"
    done = run_group(
        [sys.executable, str(Path(__file__).parents[1] / "demos" / "live.py"), "--atlas", str(atlas_folder),
         "--set", "mesh.voxel=0.01", "--touches", "8", "--out", str(out)],
        600, env=subprocess_env(),
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    curves = json.loads((out / "live.json").read_text())
    for way in ("suggested", "random"):
        assert len(curves[way]["target_error_mm"]) == 4 and all(e < 5.0 for e in curves[way]["target_error_mm"])
    assert (out / "live.png").stat().st_size > 10_000


def test_what_a_review_broke_stays_fixed(atlas_folder, atlas, tmp_path, served, monkeypatch, capsys):
    """Labels too long for OpenIGTLink or given twice, a refused list after a good one, a client
    that closes its side before its answer, idle clients holding every place, names that do not
    resolve, a label that would forge log lines."""
    touches = _touches(atlas, count=12, seed=15)
    labels = [f"t{i}" for i in range(12)]
    write_markups(tmp_path / "long.mrk.json", ["a" * 70], touches[:1] * 1e3)
    write_markups(tmp_path / "twice.mrk.json", ["L1", "L1"], touches[:2] * 1e3)
    for flag, name, words in (
        ("--targets", "long", "is longer than 64 bytes"),
        ("--pre", "twice", "label 'L1' is given twice"),
    ):
        assert brainshift(["serve", str(atlas_folder), "--port", "0", flag, str(tmp_path / f"{name}.mrk.json")]) == 2
        assert words in capsys.readouterr().err
    for flag, value in (("--allow", "nosuch.invalid"), ("--host", "nosuch.invalid")):
        assert brainshift(["serve", str(atlas_folder), "--port", "0", flag, value]) == 2
        assert f"{flag} 'nosuch.invalid': not an IPv4 address" in capsys.readouterr().err
    raw = Raw(served.server.port)
    try:
        twice = igtl.encode_point("Touches", labels[:11] + ["t0"], touches * 1e3)
        raw.send(twice)
        assert "label 't0' is given twice" in json.loads(raw.answer()[-1].content)["error"]
        nan = touches * 1e3
        nan[2, 0] = np.nan
        raw.send(igtl.encode_point("Touches", labels, touches * 1e3) + igtl.encode_point("Touches", labels, nan))
        first = json.loads(raw.answer()[-1].content)
        raw.send(igtl.encode_string("cmd", "status"))
        after = json.loads(raw.answer()[-1].content)
        # the refused list's error is the last word; no answer for the older list came after it
        assert "'t2' is not a number" in first["error"] and after["updates"] == 0
        raw.send(igtl.encode_string("cmd", "x\n[10:00:00] serve: stopped after 0 updates"))
        raw.answer()
    finally:
        raw.close()
    assert not any(line.startswith("[10:00:00]") for line in "\n".join(served.log).splitlines())
    fine = Served(_args(atlas_folder, grid=2.0))  # (an answer of ~10 MB: more than the socket holds)
    half = socket.socket()
    half.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    half.settimeout(20)
    half.connect(("127.0.0.1", fine.server.port))
    half.sendall(igtl.encode_point("Touches", labels, touches * 1e3))
    half.shutdown(socket.SHUT_WR)
    time.sleep(1.0)  # (the service sees the end of the stream before the answer has gone)
    data = b""
    while chunk := half.recv(1 << 20):
        data += chunk
    half.close()
    fine.close()
    devices, at = [], 0
    while at < len(data):  # (the whole answer, message by message)
        _, _, device, _, _, size, _ = struct.unpack(">H12s20sIIQQ", data[at : at + 58])
        devices.append(device.rstrip(b"\0").decode())
        at += 58 + size
    assert at == len(data) and devices[-1] == "BrainshiftStatus" and "BrainshiftCortex" in devices
    monkeypatch.setattr(server, "MAX_CLIENTS", 2)
    monkeypatch.setattr(server, "IDLE_S", 0.3)
    idle = [socket.create_connection(("127.0.0.1", served.server.port)) for _ in range(2)]
    time.sleep(0.6)
    raw = Raw(served.server.port)
    try:
        raw.send(igtl.encode_string("cmd", "status"))
        assert json.loads(raw.answer()[-1].content)["updates"] == 0
    finally:
        raw.close()
        for sock in idle:
            sock.close()
    assert any("its place given to a new client" in line for line in served.log)


def test_a_segmented_structure_is_moved_with_the_brain_and_sent(atlas_folder, atlas, tmp_path, capsys):
    """--structure Tumour=FILE: a closed surface inside the brain, sent back as the POLYDATA
    BrainshiftTumour at its vertices' displaced places (interpolated here, tetrahedron by
    tetrahedron, from the direct update's nodal displacement), in the client's frame."""
    from scipy.spatial import ConvexHull

    from fenics_brainshift.surfaces.files import read_surface, write_slicer_stl

    centre = atlas.points.mean(axis=0) + [0.0, 0.02, 0.0]
    rng = np.random.default_rng(0)
    ball = rng.normal(size=(60, 3))
    ball = centre + 0.012 * ball / np.linalg.norm(ball, axis=1)[:, None]
    hull = ConvexHull(ball).simplices
    write_slicer_stl(tmp_path / "tumour.stl", ball * 1e3, hull)
    touches = _touches(atlas, seed=16)
    labels = [f"t{i}" for i in range(12)]
    direct = update(atlas, Target(touches, None, labels), 1e-3)
    s = Served(_args(atlas_folder, frame="LPS", structure=[f"Tumour={tmp_path / 'tumour.stl'}"]))
    raw = Raw(s.server.port)
    try:
        raw.send(igtl.encode_point("Touches", labels, touches * 1e3 * [-1, -1, 1]))
        answer = {m.device: m for m in raw.answer()}
    finally:
        raw.close()
        s.close()
    tumour = answer["BrainshiftTumour"].content
    points, triangles = read_surface(tmp_path / "tumour.stl", 1e-3)  # (the file as the service reads it)
    assert np.array_equal(tumour.triangles, triangles) and answer["BrainshiftTumour"].metadata["frame"] == "LPS"
    index, weight, _ = MeshLocator(atlas.points, atlas.tetrahedra).weights(points)
    expected = (points + np.einsum("nj,njd->nd", weight, direct.displacement[index])) * 1e3 * [-1, -1, 1]
    assert np.allclose(tumour.points, expected, atol=1e-3)
    assert np.abs(expected - points * 1e3 * [-1, -1, 1]).max() > 0.1  # (it moved)
    for item, words in (("Tumour", "give NAME=FILE"), ("Tu-mour=x.stl", "give NAME=FILE"), ("T=none.stl", "no file")):
        assert brainshift(["serve", str(atlas_folder), "--port", "0", "--structure", item]) == 2
        assert words in capsys.readouterr().err


def test_a_service_killed_by_sigkill_loses_nothing_it_had_answered(atlas_folder, atlas, tmp_path):
    """`brainshift serve --record` as its own process, killed with SIGKILL after three updates:
    started again on the record it resumes the last list, and the record replays."""
    import signal
    import subprocess

    record = tmp_path / "killed"
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    command = [sys.executable, "-m", "fenics_brainshift.cli", "serve", str(atlas_folder), "--port", str(port)]
    command += ["--record", str(record)]
    touches = _touches(atlas, count=14, seed=17)

    def started() -> subprocess.Popen:
        process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=subprocess_env())
        for _ in range(600):
            try:
                socket.create_connection(("127.0.0.1", port), timeout=0.1).close()
                return process
            except OSError:
                time.sleep(0.05)
        process.kill()
        raise AssertionError("the service did not start")

    process = started()
    raw = Raw(port)
    try:
        for n in (8, 11, 14):
            raw.send(igtl.encode_point("Touches", [f"t{i}" for i in range(n)], touches[:n] * 1e3))
            raw.answer()
        raw.send(igtl.encode_point("Touches", [f"t{i}" for i in range(5)], touches[:5] * 1e3)[:500])  # (half sent)
        time.sleep(0.2)
        process.send_signal(signal.SIGKILL)
        process.wait(10)
    finally:
        raw.close()
    process = started()
    raw = Raw(port)
    try:
        raw.send(igtl.encode_string("cmd", "update"))
        assert json.loads(raw.answer()[-1].content)["points"] == 14
    finally:
        raw.close()
        process.terminate()
        process.wait(10)
    assert brainshift(["replay", str(record), "--atlas", str(atlas_folder)]) == 0
