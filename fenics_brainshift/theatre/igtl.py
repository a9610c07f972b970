"""OpenIGTLink codec for the theatre service: POINT, TRANSFORM, POSITION, STRING and POLYDATA
in; those and IMAGE out; always with the version-2 extended header, so metadata can travel.

Byte layouts, all big-endian, from the specification (openigtlink.org/protocols, the same text
as Documents/Protocol/*.md in github.com/openigtlink/OpenIGTLink):
- v2_header: 58 bytes; the body's CRC is CRC-64 ECMA-182 (polynomial 0x42F0E1EBA9EA3693, no
  reflection, init 0), as the reference library's igtl_util.c computes it;
- v3 extended header + metadata: EXT_HEADER_SIZE u16, METADATA_HEADER_SIZE u16, METADATA_SIZE
  u32, MSG_ID u32 -- the layout igtlMessageBase.cxx, pyigtl and 3D Slicer use (v3_proposal.md's
  draft differs); then the content; then the metadata header (count u16, then key size u16,
  value encoding u16, value size u32 per entry) and the keys and values;
- v2_point (136-byte elements), v2_transform (12 float32, column by column), v2_position
  (12, 24 or 28 bytes, as igtlPositionMessage.cxx accepts), v2_string, v2_polydata, v2_image.

Everything received is checked against the bytes it came in before any array is made; bad
bytes raise ProtocolError and nothing else. NaN or inf coordinates pass through (the caller
checks them). No unit or frame is converted here.
"""

from __future__ import annotations

import struct
import time
from array import array
from dataclasses import dataclass, field

import numpy as np
import pyigtl
from pyigtl.messages import CRC64  # crcmod's CRC-64 ECMA-182, the C library's

HEADER_SIZE = 58
MAX_BODY = {"POINT": 1 << 20, "TRANSFORM": 4096, "POSITION": 4096, "STRING": 1 << 17, "POLYDATA": 16 << 20}
_HEADER = struct.Struct(">H12s20sIIQQ")  # version, type, device, seconds, fraction / 2^32, body size, CRC
_EXTENDED = struct.Struct(">HHII")
_ASCII, _UTF8 = 3, 106  # IANA character set numbers
_POINT = np.dtype(  # v2_point, 136 bytes
    [("name", "S64"), ("group", "S32"), ("rgba", "4u1"), ("xyz", "3>f4"), ("diameter", ">f4"), ("owner", "S20")]
)


class ProtocolError(ValueError):
    """Bytes this codec does not accept, or a value it cannot send; the message says what."""


@dataclass(frozen=True)
class Header:
    version: int
    type: str
    device: str
    timestamp: float  # seconds since 1970
    body_size: int
    crc: int
    raw: bytes = field(default=b"", repr=False, compare=False)  # the 58 bytes as received (a record keeps them)


@dataclass
class Message:
    type: str
    device: str
    timestamp: float
    metadata: dict[str, str]
    content: object


@dataclass
class PointList:
    names: list[str]
    positions: np.ndarray  # (n, 3) float64


@dataclass
class Surface:
    points: np.ndarray  # (n, 3) float64
    triangles: np.ndarray  # (m, 3) int64, each index < n


# ---- receiving ------------------------------------------------------------------------------


def parse_header(data: bytes) -> Header:
    """The 58-byte header; refuses an unknown type or an oversized body before any body is read."""
    if len(data) != HEADER_SIZE:
        raise ProtocolError(f"header of {len(data)} bytes, not {HEADER_SIZE}")
    version, kind, device, seconds, fraction, body_size, crc = _HEADER.unpack(data)
    if not 1 <= version <= 3:
        raise ProtocolError(f"header version {version} is not 1, 2 or 3")
    name = kind.rstrip(b"\0")  # NUL-padded; a NUL inside, or any byte not printable ASCII, is garbage
    if not name or not all(0x20 < c < 0x7F for c in name):
        raise ProtocolError(f"message type {kind!r} is not an ASCII name")
    kind = name.decode("ascii")
    if kind not in MAX_BODY:
        raise ProtocolError(f"unsupported type {kind!r}")
    if body_size > MAX_BODY[kind]:
        raise ProtocolError(f"{kind} body of {body_size} bytes is over the {MAX_BODY[kind]}-byte limit")
    return Header(version, kind, _c_string(device), seconds + fraction / 2**32, body_size, crc, bytes(data))


def check_body(header: Header, body: bytes) -> None:
    """The body has the header's size and CRC-64."""
    if len(body) != header.body_size:
        raise ProtocolError(f"{header.type} body of {len(body)} bytes, the header said {header.body_size}")
    if CRC64(body) != header.crc:
        raise ProtocolError(f"{header.type} body fails its CRC-64 check")


def decode(header: Header, body: bytes) -> Message:
    """The message in a body (check_body it first: decode reads the bytes, not the CRC)."""
    if header.type not in _DECODERS:
        raise ProtocolError(f"unsupported type {header.type!r}")
    body = bytes(body)
    metadata, content = {}, body
    if header.version >= 2:
        if len(body) < _EXTENDED.size:
            raise ProtocolError(f"{header.type} body of {len(body)} bytes is shorter than the extended header")
        extended, meta_head, meta_size, _ = _EXTENDED.unpack_from(body)
        end = len(body) - meta_head - meta_size  # the metadata is the body's tail
        if extended < _EXTENDED.size or end < extended:
            sizes = f"extended header of {extended} bytes, metadata of {meta_head} + {meta_size} bytes"
            raise ProtocolError(f"{sizes} do not fit a {len(body)}-byte {header.type} body")
        metadata = _metadata(body[end : end + meta_head], body[end + meta_head :])
        content = body[extended:end]
    with np.errstate(invalid="ignore"):  # a signalling NaN cast to float64 is the caller's to find, not a warning
        content = _DECODERS[header.type](content)
    return Message(header.type, header.device, header.timestamp, metadata, content)


def _metadata(head: bytes, data: bytes) -> dict[str, str]:
    if not head and not data:
        return {}
    count = struct.unpack_from(">H", head)[0] if len(head) >= 2 else -1
    if len(head) != 2 + 8 * count:
        raise ProtocolError(f"metadata header of {len(head)} bytes does not hold its entry count and entries")
    entries = list(struct.iter_unpack(">HHI", head[2:]))
    if sum(key + value for key, _, value in entries) != len(data):
        raise ProtocolError(f"metadata entries do not add up to the {len(data)} bytes of keys and values")
    out, at = {}, 0
    for key_size, encoding, value_size in entries:
        key = _text(data[at : at + key_size], _UTF8, "metadata key")
        out[key] = _text(data[at + key_size : at + key_size + value_size], encoding, f"metadata value of {key!r}")
        at += key_size + value_size
    return out


def _point(content: bytes) -> PointList:
    if len(content) % _POINT.itemsize:
        raise ProtocolError(f"POINT body of {len(content)} bytes is not a whole number of 136-byte points")
    items = np.frombuffer(content, _POINT)
    return PointList([_c_string(name) for name in items["name"]], items["xyz"].astype(np.float64))


def _transform(content: bytes) -> np.ndarray:
    if len(content) != 48:
        raise ProtocolError(f"TRANSFORM body of {len(content)} bytes, not 48")
    matrix = np.eye(4)
    matrix[:3, :] = np.frombuffer(content, ">f4").reshape(4, 3).T  # R11 R21 R31, R12 ..., TX TY TZ
    return matrix


def _position(content: bytes) -> tuple[np.ndarray, np.ndarray]:
    if len(content) not in (12, 24, 28):
        raise ProtocolError(f"POSITION body of {len(content)} bytes is not 12, 24 or 28")
    values = np.frombuffer(content, ">f4").astype(np.float64)
    quaternion = np.array([0.0, 0.0, 0.0, 1.0])  # 12 bytes: position only
    if len(values) == 7:
        quaternion = values[3:]
    elif len(values) == 6:  # (x, y, z) of a unit quaternion, w >= 0; past unit norm the C library's identity
        w2 = 1.0 - values[3:] @ values[3:]
        quaternion = quaternion if w2 < 0 else np.append(values[3:], np.sqrt(w2))
    return values[:3], quaternion


def _string(content: bytes) -> str:
    if len(content) < 4:
        raise ProtocolError(f"STRING body of {len(content)} bytes has no encoding and length")
    encoding, length = struct.unpack_from(">HH", content)
    if len(content) != 4 + length:
        raise ProtocolError(f"STRING of {length} bytes in a body of {len(content)} bytes")
    return _text(content[4:], encoding, "STRING")


def _polydata(content: bytes) -> Surface:
    if len(content) < 40:
        raise ProtocolError(f"POLYDATA body of {len(content)} bytes is shorter than its 40-byte header")
    npoints, nvert, svert, nline, sline, npoly, spoly, nstrip, sstrip, nattr = struct.unpack_from(">10I", content)
    sizes = (12 * npoints, svert, sline, spoly, sstrip)
    if any(size % 4 for size in sizes):
        raise ProtocolError(f"POLYDATA cell arrays of {sizes[1:]} bytes are not whole uint32 arrays")
    starts = np.cumsum((40,) + sizes).tolist()  # where the points, each cell array and the attributes begin
    if starts[-1] + 6 * nattr > len(content):
        what = f"{npoints} points, cell arrays of {sizes[1:]} bytes and {nattr} attributes"
        raise ProtocolError(f"POLYDATA of {what} does not fit its {len(content)} bytes")
    _skip_attributes(content, starts[-1], nattr)
    points = np.frombuffer(content, ">f4", 3 * npoints, starts[0]).reshape(-1, 3).astype(np.float64)
    triangles = []
    names = ("VERTICES", "LINES", "POLYGONS", "TRIANGLE_STRIPS")
    for name, count, begin, size in zip(names, (nvert, nline, npoly, nstrip), starts[1:], sizes[1:]):
        words = np.frombuffer(content, ">u4", size // 4, begin).astype(np.int64)
        first = _walk(name, words, count, npoints)
        if name in ("POLYGONS", "TRIANGLE_STRIPS"):  # vertices and lines are checked, not kept
            triangles.append(_triangulate(name, words, first))
    return Surface(points, np.concatenate(triangles))


def _skip_attributes(content: bytes, at: int, count: int) -> None:
    # Each header is (type u8, components u8, n u32) as igtl_polydata.h lays it out, which Slicer
    # writes and reads (v2_polydata's one big-endian uint16 would put the components first); the
    # data is n * components float32. Between them the names, each NUL-terminated, padded to even.
    heads = np.frombuffer(content, [("type", "u1"), ("components", "u1"), ("n", ">u4")], count, at)
    end = at + 6 * count
    for _ in range(count):
        end = content.find(b"\0", end) + 1
        if end == 0:
            raise ProtocolError(f"POLYDATA has {count} attributes but not as many NUL-terminated names")
    end += (end - at - 6 * count) % 2 + 4 * int((heads["n"].astype(np.int64) * heads["components"]).sum())
    if end != len(content):
        raise ProtocolError(f"POLYDATA sections end at byte {end} of its {len(content)}-byte body")


def _walk(name: str, words: np.ndarray, count: int, npoints: int) -> np.ndarray:
    """Where each cell ([n, i_0 .. i_n-1]) of a cell array begins; checks the array is whole cells,
    as many as the header said, with every point index < npoints."""
    step = int(words[0]) + 1 if len(words) else 1
    if len(words) % step == 0 and (words[::step] == step - 1).all():  # one cell size throughout: triangles
        first = np.arange(0, len(words), step)
    else:  # mixed sizes: walk the cells (8 bytes a cell kept, not a Python int's 36)
        first, at, values = array("q"), 0, memoryview(words)
        while at < len(values):
            if len(first) == count:
                raise ProtocolError(f"POLYDATA {name}: more than the header's {count} cells")
            first.append(at)
            at += values[at] + 1
        if at != len(values):
            raise ProtocolError(f"POLYDATA {name}: the last cell runs past its {4 * len(words)}-byte array")
        first = np.frombuffer(first, np.int64)
    if len(first) != count:
        raise ProtocolError(f"POLYDATA {name}: {len(first)} cells, the header said {count}")
    indices = np.ones(len(words), bool)
    indices[first] = False
    if indices.any() and words[indices].max() >= npoints:
        raise ProtocolError(f"POLYDATA {name}: point index {words[indices].max()} for {npoints} points")
    return first


def _triangulate(name: str, words: np.ndarray, first: np.ndarray) -> np.ndarray:
    corners = words[first]
    if (corners < 3).any():
        raise ProtocolError(f"POLYDATA {name}: a cell of {corners.min()} points")
    per_cell = corners - 2
    local = np.arange(per_cell.sum()) - np.repeat(np.cumsum(per_cell) - per_cell, per_cell)  # 0 .. n-3 in its cell
    base = np.repeat(first + 1, per_cell)  # each triangle's cell's first point
    if name == "POLYGONS":  # fans (i_0, i_k+1, i_k+2), exact for triangles, fine for convex polygons
        return np.stack([words[base], words[base + local + 1], words[base + local + 2]], axis=1)
    a, b, c = words[base + local], words[base + local + 1], words[base + local + 2]
    odd = local % 2 == 1  # every other triangle of a strip is flipped to keep the orientation, as VTK's
    return np.stack([np.where(odd, b, a), np.where(odd, a, b), c], axis=1)


_DECODERS = {"POINT": _point, "TRANSFORM": _transform, "POSITION": _position, "STRING": _string, "POLYDATA": _polydata}


def _c_string(raw: bytes) -> str:
    return raw.split(b"\0", 1)[0].decode("utf-8", "replace")


def _text(raw: bytes, encoding: int, what: str) -> str:
    codec = {_ASCII: "ascii", _UTF8: "utf-8"}.get(encoding)
    if codec is None:
        raise ProtocolError(f"{what} in character set {encoding}, not US-ASCII (3) or UTF-8 (106)")
    try:
        return raw.decode(codec)
    except UnicodeDecodeError:
        raise ProtocolError(f"{what} is not valid {codec}") from None


class Reader:
    """Feed bytes as they arrive; yields complete (Header, body) pairs; raises ProtocolError on a
    bad header (the connection is then closed by the caller)."""

    def __init__(self) -> None:
        self._buffer = bytearray()
        self._header: Header | None = None

    @property
    def pending(self) -> int:
        """Bytes received towards the next message: its header (once read) and its body so far."""
        return len(self._buffer) + (HEADER_SIZE if self._header else 0)

    def feed(self, data: bytes) -> list[tuple[Header, bytes]]:
        # Only what the current header or body still needs is copied in: never more than a
        # header, or a body parse_header has let through, whatever size of chunk arrives.
        view, out = memoryview(data).cast("B"), []
        while True:
            want = HEADER_SIZE if self._header is None else self._header.body_size
            take = want - len(self._buffer)
            self._buffer += view[:take]
            view = view[take:]
            if len(self._buffer) < want:
                return out
            chunk, self._buffer = bytes(self._buffer), bytearray()
            if self._header is None:
                self._header = parse_header(chunk)
            else:
                out.append((self._header, chunk))
                self._header = None


# ---- sending --------------------------------------------------------------------------------


def encode_point(device: str, names: list[str], positions, metadata: dict | None = None) -> bytes:
    xyz = np.asarray(positions, dtype=np.float64)
    if xyz.shape != (len(names), 3):
        raise ProtocolError(f"POINT positions of shape {xyz.shape} for {len(names)} names")
    items = np.zeros(len(names), _POINT)
    items["name"] = [_encode(name, "point name", 64, ascii_only=False)[0] for name in names]
    items["rgba"] = (255, 255, 0, 255)  # pyigtl's default colour
    items["xyz"] = xyz
    return _frame("POINT", device, items.tobytes(), metadata)


def encode_string(device: str, text: str, metadata: dict | None = None) -> bytes:
    raw, encoding = _encode(text, "STRING", 0xFFFF, ascii_only=False)
    return _frame("STRING", device, struct.pack(">HH", encoding, len(raw)) + raw, metadata)


def encode_polydata(device: str, points, triangles, metadata: dict | None = None) -> bytes:
    xyz, tri = np.asarray(points, dtype=np.float64), np.asarray(triangles)
    tri = np.zeros((0, 3), np.int64) if tri.size == 0 else tri
    if xyz.ndim != 2 or xyz.shape[1] != 3 or tri.ndim != 2 or tri.shape[1] != 3 or tri.dtype.kind not in "iu":
        raise ProtocolError(f"POLYDATA needs (n, 3) points and (m, 3) integer triangles, not {xyz.shape}, {tri.shape}")
    if tri.size and (tri.min() < 0 or tri.max() >= len(xyz)):
        raise ProtocolError(f"POLYDATA triangle index outside 0 .. {len(xyz) - 1}")
    cells = np.empty((len(tri), 4), ">u4")
    cells[:, 0], cells[:, 1:] = 3, tri  # [3, i, j, k] per polygon
    head = struct.pack(">10I", len(xyz), 0, 0, 0, 0, len(tri), cells.nbytes, 0, 0, 0)
    return _frame("POLYDATA", device, head + xyz.astype(">f4").tobytes() + cells.tobytes(), metadata)


def encode_image(device: str, data, ijk_to_ras, metadata: dict | None = None, frame: str = "RAS") -> bytes:
    """data (k, j, i) or (k, j, i, components), sent as float32; ijk_to_ras with the spacing in
    its columns. pyigtl's ImageMessage packs the body as the reference library and Slicer read it:
    the columns as they are, the image centre ijk_to_ras @ ((size - 1) / 2, 1) as the position,
    voxels little-endian and so flagged; only its coordinate flag must be set, from its 'lps' default."""
    voxels, matrix = np.asarray(data), np.asarray(ijk_to_ras, dtype=np.float64)
    if voxels.ndim not in (3, 4) or not 0 < max(voxels.shape[:3]) <= 0xFFFF or voxels.shape[3:] > (255,):
        raise ProtocolError(f"IMAGE of shape {voxels.shape}: not (k, j, i) or (k, j, i, components) within 65535")
    if matrix.shape != (4, 4):
        raise ProtocolError(f"IMAGE ijk_to_ras of shape {matrix.shape}, not (4, 4)")
    voxels = np.ascontiguousarray(voxels, dtype="<f4")
    world = {"RAS": "ras", "LPS": "lps"}[frame]  # (the frame the matrix is in, said in the IMAGE's own flag)
    image = pyigtl.ImageMessage(voxels, matrix, world_coordinate_system=world)
    return _frame("IMAGE", device, image.pack()[HEADER_SIZE:], metadata)  # its header version 1: body = content


def encode_transform(device: str, matrix, metadata: dict | None = None) -> bytes:
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape != (4, 4) or not np.array_equal(m[3], [0, 0, 0, 1]):
        raise ProtocolError("TRANSFORM needs a 4x4 affine matrix (last row 0 0 0 1)")
    return _frame("TRANSFORM", device, m[:3].T.astype(">f4").tobytes(), metadata)  # column by column


def encode_position(device: str, position, quaternion=(0, 0, 0, 1), metadata: dict | None = None) -> bytes:
    p, q = np.asarray(position, dtype=np.float64), np.asarray(quaternion, dtype=np.float64)
    if p.shape != (3,) or q.shape != (4,):
        raise ProtocolError(f"POSITION needs a 3-vector and an (x, y, z, w) quaternion, not {p.shape}, {q.shape}")
    return _frame("POSITION", device, np.concatenate([p, q]).astype(">f4").tobytes(), metadata)


def _encode(text: str, what: str, limit: int, ascii_only: bool = True) -> tuple[bytes, int]:
    if not isinstance(text, str):
        raise ProtocolError(f"{what} {text!r} is not a str")
    try:
        raw, encoding = text.encode("ascii"), _ASCII
    except UnicodeEncodeError:
        if ascii_only:
            raise ProtocolError(f"{what} {text!r} is not ASCII") from None
        raw, encoding = text.encode("utf-8"), _UTF8
    if len(raw) > limit:
        raise ProtocolError(f"{what} {text[:30]!r}... is longer than {limit} bytes")
    return raw, encoding


def _frame(kind: str, device: str, content: bytes, metadata: dict | None) -> bytes:
    """Header version 2: header, extended header, content, metadata header, keys and values."""
    name, metadata = _encode(device, "device name", 20)[0], metadata or {}
    if len(metadata) > 8191:  # the metadata header's size is a uint16
        raise ProtocolError(f"{len(metadata)} metadata entries, more than a metadata header holds")
    head, pairs = struct.pack(">H", len(metadata)), b""
    for key, value in metadata.items():
        raw_key = _encode(key, "metadata key", 0xFFFF)[0]  # keys are ASCII (v3), values any character
        raw_value, encoding = _encode(value, f"metadata value of {key!r}", 0xFFFFFFFF, ascii_only=False)
        head += struct.pack(">HHI", len(raw_key), encoding, len(raw_value))
        pairs += raw_key + raw_value
    body = _EXTENDED.pack(_EXTENDED.size, len(head), len(pairs), 0) + content + head + pairs
    now = time.time()
    seconds = int(now)
    fraction = min(int((now - seconds) * 2**32), 2**32 - 1)
    return _HEADER.pack(2, kind.encode("ascii"), name, seconds, fraction, len(body), CRC64(body)) + body
