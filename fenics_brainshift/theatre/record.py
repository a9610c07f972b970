"""The record of a live operation (`brainshift serve --record DIR`) and its replay.

DIR/messages.bin holds every message received, as it arrived: per message a mark, the time,
the client's number, the size, the message's own bytes (header and body, unchanged: a message
the server dropped is kept too, and dropped again on replay) and a CRC-32 of the record. Each
start of the service adds a record of client 0 first: its options and the client whose points
it resumed. Client numbers run on across starts. DIR/updates.jsonl holds one line per update:
the client, how many messages (of every client) had arrived, the status sent and the weights.
Both are appended and flushed as they happen, and both are synced to disk before the answer
goes out: a server killed at any moment leaves every message it had received and every update
it had answered readable; the next start cuts off a record the kill left half-written.

`brainshift replay DIR` feeds the recorded messages through the same sessions as the server
(session.py), in the same order, updating where the server did, and checks each update against
the recorded weights and residuals.
"""

from __future__ import annotations

import json
import os
import struct
import time
import zlib
from pathlib import Path

import numpy as np

from .. import json_text
from ..errors import InputError
from . import igtl

_RECORD = struct.Struct(">4sdII")  # magic, time, client, size; then the message, then a CRC-32 of both
_MAGIC = b"BSR1"
TOLERANCE = 1e-9  # of a weight, and of a residual in mm, between an update and its replay


class Recorder:
    """Appends to DIR's record; opened by a start of the service with its options and the
    client it resumed (None: a fresh case)."""

    def __init__(self, folder: Path, options: dict, resumed: int | None = None):
        if folder.exists() and not folder.is_dir():
            raise InputError(f"--record: '{folder}' is a file; give a folder (made if missing)")
        folder.mkdir(parents=True, exist_ok=True)
        self.folder = folder
        repair(folder)
        records, _ = _scan(folder / "messages.bin")
        self.first_client = max((client for _, client, _ in records), default=0) + 1
        self.count = sum(client != 0 for _, client, _ in records)  # messages of every client so far
        self._messages = open(folder / "messages.bin", "ab")  # noqa: SIM115 (open for the server's life)
        self._updates = open(folder / "updates.jsonl", "a", encoding="utf-8")  # noqa: SIM115
        start = {"start": time.time(), "options": options, "resumed": resumed}
        self._write(0, json_text.dumps(start, indent=None).encode())

    def _write(self, client: int, payload: bytes, when: float | None = None) -> None:
        record = _RECORD.pack(_MAGIC, time.time() if when is None else when, client, len(payload)) + payload
        self._messages.write(record + struct.pack(">I", zlib.crc32(record)))
        self._messages.flush()

    def received(self, client: int, header: igtl.Header, body: bytes, arrived: float | None = None) -> None:
        self._write(client, _raw_header(header) + bytes(body), arrived)
        self.count += 1

    def answered(self, client: int, messages: list[bytes], seconds: float) -> None:
        from .session import status_of

        line = {"client": client, "after": self.count, "seconds": seconds, "status": status_of(messages)}
        self._updates.write(json_text.dumps(line, indent=None) + "\n")
        self._updates.flush()
        os.fsync(self._messages.fileno())
        os.fsync(self._updates.fileno())

    def close(self) -> None:
        self._messages.close()
        self._updates.close()


def _raw_header(header: igtl.Header) -> bytes:
    """The header's bytes as received (or packed again from its fields, for one made here)."""
    if header.raw:
        return header.raw
    seconds = int(header.timestamp)
    fraction = min(int((header.timestamp - seconds) * 2**32), 2**32 - 1)
    name = header.device.encode("utf-8")[:20]
    return struct.pack(
        ">H12s20sIIQQ",
        header.version,
        header.type.encode("ascii"),
        name,
        seconds,
        fraction,
        header.body_size,
        header.crc,
    )


def _scan(path: Path) -> tuple[list[tuple[float, int, bytes]], int]:
    """((time, client, payload) of every whole record, the bytes they fill) of a messages.bin."""
    data = path.read_bytes() if path.is_file() else b""
    out, at = [], 0
    while at + _RECORD.size + 4 <= len(data):
        magic, when, client, size = _RECORD.unpack_from(data, at)
        end = at + _RECORD.size + size
        # (a record cut by a kill inside it, or bytes that are not one, end the record)
        if magic != _MAGIC or end + 4 > len(data) or struct.unpack_from(">I", data, end)[0] != zlib.crc32(data[at:end]):
            break
        out.append((when, client, data[at + _RECORD.size : end]))
        at = end + 4
    return out, at


def _scan_updates(path: Path) -> tuple[list[dict], int]:
    """(every whole, well-formed line of an updates.jsonl, the bytes they fill)."""
    data = path.read_bytes() if path.is_file() else b""
    out, at = [], 0
    for line in data.splitlines(keepends=True):
        if not line.endswith(b"\n"):
            break  # (cut by a kill)
        try:
            update = json.loads(line)
        except ValueError:
            break
        if not (
            isinstance(update, dict)
            and all(isinstance(update.get(k), int) for k in ("client", "after"))
            and isinstance(update.get("status"), dict)
        ):
            break
        out.append(update)
        at += len(line)
    return out, at


def repair(folder: Path) -> str | None:
    """Cut off what a kill left half-written at the end of a record's files (else what a next
    start appends would be unreadable behind it); a line saying what was cut, or None."""
    cut = []
    for name, scan in (("messages.bin", _scan), ("updates.jsonl", _scan_updates)):
        path = folder / name
        good = scan(path)[1]
        if path.is_file() and path.stat().st_size > good:
            cut.append(f"{name}: {path.stat().st_size - good} bytes after byte {good}")
            with open(path, "r+b") as f:
                f.truncate(good)
    return f"cut off what a kill left half-written ({'; '.join(cut)})" if cut else None


def read_messages(folder: Path) -> list[tuple[float, int, bytes]]:
    """(time, client, the message's bytes) of every whole message recorded (starts left out)."""
    return [r for r in _read(folder)[0] if r[1] != 0]


def _read(folder: Path) -> tuple[list, list[dict]]:
    """(the records, the updates) of a record folder, or InputError saying what is damaged."""
    path = folder / "messages.bin"
    if not path.is_file():
        raise InputError(f"replay: '{folder}' holds no messages.bin (a folder of `brainshift serve --record`?)")
    records, good = _scan(path)
    if good < path.stat().st_size:
        raise InputError(
            f"replay: {path} is damaged after byte {good} of {path.stat().st_size} (its {len(records)} records "
            f"before it are whole); a service started on the folder cuts off a record a kill left half-written"
        )
    updates_path = folder / "updates.jsonl"
    updates, good = _scan_updates(updates_path)
    size = updates_path.stat().st_size if updates_path.is_file() else 0
    if good < size:
        raise InputError(
            f"replay: {updates_path} is damaged at line {len(updates) + 1} (not an update's record); the lines "
            f"before it are whole"
        )
    return records, updates


def play(folder: Path, new_session, answer: bool = True, records=None, updates=None):
    """Feed the recorded messages, in their order, through a session per recorded client
    (new_session(case or None): a start's new clients begin with the case it resumed), making
    each recorded update where the server made it (answer=True) -> (sessions by client,
    [(recorded, replayed status)], the client whose last update was the latest good one)."""
    from .session import status_of

    if records is None:
        records, updates = _read(folder)
    due: dict[int, list[dict]] = {}
    for u in updates:
        due.setdefault(u["after"], []).append(u)
    sessions, pairs, count, resumed = {}, [], 0, None
    for arrived, client, raw in records:
        if client == 0:  # a start of the service: its new clients begin with the case it resumed
            start = json.loads(raw)
            resumed = sessions[start["resumed"]].case if start.get("resumed") in sessions else None
            continue
        if client not in sessions:
            sessions[client] = new_session(resumed)
        count += 1
        try:
            header = igtl.parse_header(raw[: igtl.HEADER_SIZE])
            body = raw[igtl.HEADER_SIZE :]
            igtl.check_body(header, body)
            sessions[client].handle(igtl.decode(header, body), arrived)
        except igtl.ProtocolError:
            pass  # (the server dropped it too)
        for recorded in due.pop(count, []):
            if answer and recorded["client"] in sessions:
                pairs.append((recorded, status_of(sessions[recorded["client"]].answer())))
    good = [u["client"] for u in updates if "error" not in u["status"]]
    return sessions, pairs, (good[-1] if good else None), sum(len(v) for v in due.values())


def options_of(folder: Path) -> dict | None:
    """The options of the record's last start (None for a record without one)."""
    starts = [json.loads(raw) for _, client, raw in _read(folder)[0] if client == 0]
    return starts[-1].get("options") if starts else None


def replay(folder: Path, new_session, options: dict | None = None) -> list[str]:
    """Re-run a recorded operation; InputError unless every update gives the recorded answer."""
    records, updates = _read(folder)
    starts = [json.loads(raw) for _, client, raw in records if client == 0]
    if options is not None:
        for start in starts:
            for key, value in (start.get("options") or {}).items():
                if key in options and options[key] != value:
                    flag = key.replace("_", "-")
                    raise InputError(
                        f"replay: the operation was served with --{flag} {value!r}, not {options[key]!r}: give the same"
                    )
    sessions, pairs, _, unreached = play(folder, new_session, records=records, updates=updates)
    if unreached:
        raise InputError(
            f"replay: {unreached} of the {len(updates)} recorded updates come after the last recorded message: "
            f"messages.bin is missing messages (copied while the service ran?)"
        )
    worst, first_bad = 0.0, None
    for k, (recorded, again) in enumerate(pairs):
        a, b = recorded["status"], again
        difference = _difference(a, b)
        worst = max(worst, difference)
        if difference > TOLERANCE and first_bad is None:
            first_bad = (k, a.get("residual_mm"), b.get("residual_mm"), difference)
    if first_bad is not None:
        k, was, now, d = first_bad
        raise InputError(
            f"replay: update {k + 1} of {len(pairs)} differs from the record (residual {was} mm recorded, {now} mm "
            f"now; largest difference {d:.3g}): another atlas, or another version of the update"
        )
    messages = sum(client != 0 for _, client, _ in records)
    return [
        f"replay: {messages} messages from {len(sessions)} client(s) over {len(starts)} start(s), {len(pairs)} "
        f"updates: each the recorded answer (largest difference {worst:.2g} in a weight or a residual in mm)"
    ]


def _difference(a: dict, b: dict) -> float:
    """The largest difference between two statuses' weights and residuals (inf if one failed)."""
    if ("error" in a) != ("error" in b):
        return float("inf")
    if "error" in a:
        return 0.0 if a["error"] == b["error"] else float("inf")
    out = 0.0
    for key in ("prior_residual_mm", "residual_mm", "leave_one_out_mm"):
        if (a.get(key) is None) != (b.get(key) is None):
            return float("inf")
        if a.get(key) is not None:
            try:
                out = max(out, abs(float(a[key]) - float(b[key])))
            except (TypeError, ValueError):
                return float("inf")
    try:
        wa, wb = np.asarray(a.get("weights", []), dtype=float), np.asarray(b.get("weights", []), dtype=float)
    except (TypeError, ValueError):
        return float("inf")
    if wa.shape != wb.shape:
        return float("inf")
    return max(out, float(np.abs(wa - wb).max(initial=0.0)))
