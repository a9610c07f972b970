"""The record of a live operation (`brainshift serve --record DIR`) and its replay.

DIR/messages.bin holds every message received, as it arrived: per message a mark, the time,
the client's number, the size, the message's own bytes (header and body, unchanged: a message
the server dropped is kept too, and dropped again on replay) and a CRC-32 of the record. DIR/updates.jsonl holds
one line per update: the client, how many of its messages had arrived, the status sent and
the fitted weights. Both are appended and flushed as they happen, and updates.jsonl is synced
to disk before the answer goes out: a server killed at any moment leaves every message it
had received and every update it had answered readable (a record cut inside its last message
is read up to that message).

`brainshift replay DIR` feeds the recorded messages through the same sessions as the server
(session.py) and checks that each update gives the recorded weights and residuals.
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
    def __init__(self, folder: Path):
        folder.mkdir(parents=True, exist_ok=True)
        self.folder = folder
        self._messages = open(folder / "messages.bin", "ab")  # noqa: SIM115 (open for the server's life)
        self._updates = open(folder / "updates.jsonl", "a", encoding="utf-8")  # noqa: SIM115

    def received(self, client: int, header: igtl.Header, body: bytes, when: float | None = None) -> None:
        raw = _raw_header(header)
        record = _RECORD.pack(_MAGIC, when or time.time(), client, len(raw) + len(body)) + raw + bytes(body)
        self._messages.write(record + struct.pack(">I", zlib.crc32(record)))
        self._messages.flush()

    def answered(self, client: int, after: int, messages: list[bytes], seconds: float) -> None:
        from .session import status_of

        status = status_of(messages)
        line = {"client": client, "after": after, "seconds": seconds, "status": status}
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


def read_messages(folder: Path) -> list[tuple[float, int, bytes]]:
    """(time, client, the message's bytes) of every whole message recorded."""
    path = folder / "messages.bin"
    if not path.is_file():
        raise InputError(f"replay: '{folder}' holds no messages.bin (a folder of `brainshift serve --record`?)")
    data, out, at = path.read_bytes(), [], 0
    while at + _RECORD.size + 4 <= len(data):
        magic, when, client, size = _RECORD.unpack_from(data, at)
        end = at + _RECORD.size + size
        # (a record cut by a kill inside it, or bytes that are not one, end the record)
        if magic != _MAGIC or end + 4 > len(data) or struct.unpack_from(">I", data, end)[0] != zlib.crc32(data[at:end]):
            break
        out.append((when, client, data[at + _RECORD.size : end]))
        at = end + 4
    return out


def read_updates(folder: Path) -> list[dict]:
    path = folder / "updates.jsonl"
    out = []
    if path.is_file():
        for line in path.read_text(encoding="utf-8").splitlines():
            try:
                out.append(json.loads(line))
            except ValueError:
                break  # (a line cut by a kill)
    return out


def play(folder: Path, new_session, answer: bool = True):
    """Feed the recorded messages through new sessions (one per recorded client), updating
    where the record did (answer=True) -> (sessions by client, [(recorded, replayed status)])."""
    updates = read_updates(folder)
    due: dict[tuple[int, int], list[dict]] = {}
    for u in updates:
        due.setdefault((u["client"], u["after"]), []).append(u)
    sessions, counts, pairs = {}, {}, []
    for _, client, raw in read_messages(folder):
        session = sessions.get(client) or sessions.setdefault(client, new_session())
        counts[client] = counts.get(client, 0) + 1
        try:
            header = igtl.parse_header(raw[: igtl.HEADER_SIZE])
            body = raw[igtl.HEADER_SIZE :]
            igtl.check_body(header, body)
            session.handle(igtl.decode(header, body))
        except igtl.ProtocolError:
            pass  # (the server dropped it too)
        for recorded in due.get((client, counts[client]), []):
            if answer:
                from .session import status_of

                pairs.append((recorded, status_of(session.answer())))
    return sessions, pairs


def replay(folder: Path, new_session) -> list[str]:
    """Re-run a recorded operation; InputError unless every update gives the recorded answer."""
    sessions, pairs = play(folder, new_session)
    worst, first_bad = 0.0, None
    for k, (recorded, again) in enumerate(pairs):
        a, b = recorded["status"], again
        difference = _difference(a, b)
        worst = max(worst, difference)
        if difference > TOLERANCE and first_bad is None:
            first_bad = (k, a.get("residual_mm"), b.get("residual_mm"), difference)
    messages = len(read_messages(folder))
    if first_bad is not None:
        k, was, now, d = first_bad
        raise InputError(
            f"replay: update {k + 1} of {len(pairs)} differs from the record (residual {was} mm recorded, {now} mm "
            f"now; largest difference {d:.3g}): another atlas, or another version of the update"
        )
    return [
        f"replay: {messages} messages from {len(sessions)} client(s), {len(pairs)} updates: each the recorded answer "
        f"(largest difference {worst:.2g} in a weight or a residual in mm)"
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
            out = max(out, abs(a[key] - b[key]))
    wa, wb = np.asarray(a.get("weights", []), dtype=float), np.asarray(b.get("weights", []), dtype=float)
    if wa.shape != wb.shape:
        return float("inf")
    return max(out, float(np.abs(wa - wb).max(initial=0.0)))
