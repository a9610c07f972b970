"""The OpenIGTLink codec against references outside it: pyigtl's own pack and unpack, messages
packed here by hand from the specification's tables, a bitwise CRC-64 ECMA-182; and bad bytes,
by hand and by a seeded fuzz, raise ProtocolError and nothing else."""

from __future__ import annotations

import struct

import numpy as np
import pyigtl
import pytest
from pyigtl.messages import CRC64, MessageBase

from fenics_brainshift.theatre import igtl

pytestmark = pytest.mark.usefixtures("serial_only")

META = {"frame": "RAS", "units": "mm", "note": "déjà vu"}  # a UTF-8 value too


def crc64_ecma(data: bytes) -> int:
    """CRC-64 ECMA-182 bit by bit: polynomial 0x42F0E1EBA9EA3693, MSB first, init 0, no final xor."""
    crc = 0
    for byte in data:
        crc ^= byte << 56
        for _ in range(8):
            crc = ((crc << 1) ^ 0x42F0E1EBA9EA3693) if crc & (1 << 63) else crc << 1
            crc &= (1 << 64) - 1
    return crc


def pyigtl_unpack(data: bytes):
    fields = MessageBase.parse_header(data[:58])
    message = MessageBase.create_message(fields["message_type"])
    message.unpack(fields, data[58:])
    return fields, message


def pyigtl_pack(message, version: int, metadata: dict) -> bytes:
    message.header_version, message.metadata = version, metadata
    return message.pack()


def read(data: bytes) -> igtl.Message:
    """As the server reads: through the Reader, in uneven pieces, then check_body and decode."""
    reader, out = igtl.Reader(), []
    for start in range(0, len(data), 37):
        out += reader.feed(data[start : start + 37])
    assert len(out) == 1 and reader.pending == 0
    igtl.check_body(*out[0])
    return igtl.decode(*out[0])


def frame(kind: bytes, content: bytes, version: int = 1, crc: int | None = None) -> bytes:
    """A message packed by hand from v2_header (version 1: the body is the content)."""
    crc = crc64_ecma(content) if crc is None else crc
    return struct.pack(">H12s20sIIQQ", version, kind, b"hand", 1_700_000_000, 1 << 31, len(content), crc) + content


def split(data: bytes) -> tuple[igtl.Header, bytes]:
    return igtl.parse_header(data[:58]), data[58:]


def content_of(data: bytes) -> bytes:
    """The content section of a version-2 message, by the extended header's sizes."""
    extended, meta_head, meta_size, _ = struct.unpack(">HHII", data[58:70])
    return data[58 + extended : len(data) - meta_head - meta_size]


# ---- what igtl sends, read by pyigtl (and by hand) -------------------------------------------


def test_crc_is_ecma_182_and_the_header_is_version_2():
    assert crc64_ecma(b"123456789") == 0x6C40DF5F0B497347  # the catalogued check value
    data = igtl.encode_string("status", "ready", META)
    version, kind, device, _, _, size, crc = struct.unpack(">H12s20sIIQQ", data[:58])
    assert (version, kind, device) == (2, b"STRING".ljust(12, b"\0"), b"status".ljust(20, b"\0"))
    assert size == len(data) - 58 and crc == crc64_ecma(data[58:])


def test_point_is_read_by_pyigtl():
    names, xyz = ["entry", "target", "é"], np.array([[1.5, -20.25, 30.0], [0.0, 1e-3, -7.0], [1e5, 2.0, 3.0]])
    fields, message = pyigtl_unpack(igtl.encode_point("fiducials", names, xyz, META))
    assert fields["header_version"] == 2 and message.device_name == "fiducials"
    assert message.names == names and message.metadata == META
    assert np.array_equal(np.array(message.positions), xyz.astype(np.float32))


def test_string_is_read_by_pyigtl():
    for text in ["update 3 done", "Läsion ≤ 2 mm", ""]:
        _, message = pyigtl_unpack(igtl.encode_string("status", text, META))
        assert (message.string, message.device_name, message.metadata) == (text, "status", META)


def test_transform_is_read_by_pyigtl():
    c, s = np.cos(0.3), np.sin(0.3)
    matrix = np.array([[c, -s, 0, 10.5], [s, c, 0, -20], [0, 0, 1, 30.25], [0, 0, 0, 1]])
    _, message = pyigtl_unpack(igtl.encode_transform("ToolToRAS", matrix, META))
    assert np.array_equal(message.matrix, matrix.astype(np.float32)) and message.metadata == META


@pytest.mark.parametrize("components", [None, 3])
def test_image_is_read_by_pyigtl_and_centred_as_slicer_reads_it(components):
    rng = np.random.default_rng(1)
    shape = (4, 5, 6) if components is None else (4, 5, 6, components)  # (k, j, i[, c])
    data = rng.normal(size=shape).astype(np.float32)
    rotation = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    ijk_to_ras = np.eye(4)
    ijk_to_ras[:3, :3] = rotation * [0.5, 0.75, 2.0]  # spacing in the columns
    ijk_to_ras[:3, 3] = [-100.0, 20.0, 35.5]
    packed = igtl.encode_image("displacement", data, ijk_to_ras, META)
    _, message = pyigtl_unpack(packed)
    assert message.world_coordinate_system == "ras" and message.metadata == META
    assert np.array_equal(message.image, data)
    np.testing.assert_allclose(message.ijk_to_world_matrix, ijk_to_ras, atol=1e-4)
    # v2_image by hand: columns with spacing, then the image centre, as OpenIGTLinkIO's
    # ImageConverter reads it (position = corner + M (size - 1) / 2), voxels little-endian
    content = content_of(packed)
    version, ncomp, scalar, endian, coord, *rest = struct.unpack(">HBBBBHHH12f6H", content[:72])
    size, columns, centre = np.array(rest[:3]), np.array(rest[3:12]).reshape(3, 3).T, np.array(rest[12:15])
    assert (version, ncomp, scalar, endian, coord) == (1, components or 1, 10, 2, 1)
    assert tuple(size) == (6, 5, 4) and tuple(rest[15:]) == (0, 0, 0, 6, 5, 4)  # the whole volume
    np.testing.assert_allclose(columns, ijk_to_ras[:3, :3], atol=1e-6)
    np.testing.assert_allclose(centre, ijk_to_ras[:3, 3] + ijk_to_ras[:3, :3] @ ((size - 1) / 2), atol=1e-4)
    assert np.array_equal(np.frombuffer(content[72:], "<f4").reshape(shape), data)


def test_position_is_the_specs_28_bytes():
    packed = igtl.encode_position("Stylus", [1.5, -2.0, 3.25], [0.0, 0.6, 0.0, 0.8], META)
    assert struct.unpack(">7f", content_of(packed)) == pytest.approx((1.5, -2.0, 3.25, 0.0, 0.6, 0.0, 0.8))
    # pyigtl's PositionMessage is not v2_position: it reads 152-byte elements, so none here
    _, message = pyigtl_unpack(packed)
    assert message.positions == [] and message.metadata == META


# ---- what pyigtl (or the specification by hand) sends, read by igtl --------------------------


@pytest.mark.parametrize("version", [1, 2])
def test_pyigtl_messages_are_read(version):
    meta = {"frame": "RAS", "units": "mm"} if version == 2 else {}  # pyigtl cannot pack a non-ASCII value
    xyz = np.array([[1.5, 2.0, -3.0], [4.0, 5.25, 6.0]])
    message = read(pyigtl_pack(pyigtl.PointMessage(xyz, names=["a", "b"], device_name="points"), version, meta))
    assert (message.type, message.device, message.metadata) == ("POINT", "points", meta)
    assert message.content.names == ["a", "b"] and np.array_equal(message.content.positions, xyz)

    assert read(pyigtl_pack(pyigtl.StringMessage("hello theatre"), version, meta)).content == "hello theatre"

    matrix = np.array([[0.0, -1, 0, 10], [1, 0, 0, 20.5], [0, 0, 1, -30], [0, 0, 0, 1]])
    message = read(pyigtl_pack(pyigtl.TransformMessage(matrix, timestamp=1234.5), version, meta))
    assert np.array_equal(message.content, matrix) and message.timestamp == 1234.5 and message.metadata == meta


def test_position_bodies_of_the_spec_and_pyigtls_refused():
    for values, quaternion in [
        ((1.0, 2.0, 3.0), (0.0, 0.0, 0.0, 1.0)),  # position only
        ((1.0, 2.0, 3.0, 0.0, 0.6, 0.0), (0.0, 0.6, 0.0, 0.8)),  # w from the unit norm
        ((1.0, 2.0, 3.0, 0.5, 0.5, 0.5, -0.5), (0.5, 0.5, 0.5, -0.5)),
    ]:
        position, q = read(frame(b"POSITION", struct.pack(f">{len(values)}f", *values))).content
        assert np.array_equal(position, [1.0, 2.0, 3.0]) and np.allclose(q, quaternion)
    packed = pyigtl.PositionMessage([1.0, 2.0, 3.0], [0.0, 0.0, 0.0, 1.0], device_name="tool").pack()
    with pytest.raises(igtl.ProtocolError, match="POSITION body of 152 bytes"):
        read(packed)


def polydata_by_hand(index: int = 5) -> bytes:
    """v2_polydata: 10 uint32 counts and sizes, big-endian float32 points, uint32 cell arrays,
    one point-scalar attribute (header, NUL-terminated name, padding, float32 data)."""
    points = struct.pack(">18f", *(np.arange(18) * 1.5 - 4))  # 6 points
    vertices, lines = [1, 0, 1, 5], [2, 0, 1]
    polygons = [3, 0, 1, 2, 4, 0, 2, 3, 4]  # a triangle and a quad
    strips = [5, 1, 2, 3, 4, index]
    head = struct.pack(">10I", 6, 2, 16, 1, 12, 2, 36, 1, 24, 1)
    cells = struct.pack(f">{len(vertices + lines + polygons + strips)}I", *vertices, *lines, *polygons, *strips)
    attribute = struct.pack(">BBI", 0x00, 1, 6) + b"temp\0" + b"\0" + struct.pack(">6f", *range(6))
    return head + points + cells + attribute


def test_polydata_by_hand_quad_fanned_strip_alternated():
    surface = read(frame(b"POLYDATA", polydata_by_hand())).content
    assert np.array_equal(surface.points, np.arange(18).reshape(6, 3) * 1.5 - 4)
    expected = [[0, 1, 2], [0, 2, 3], [0, 3, 4], [1, 2, 3], [3, 2, 4], [3, 4, 5]]
    assert surface.triangles.dtype == np.int64 and surface.triangles.tolist() == expected


def test_polydata_round_trip_and_its_bytes():
    rng = np.random.default_rng(2)
    points, triangles = rng.normal(size=(50, 3)) * 40, rng.integers(0, 50, size=(80, 3))
    packed = igtl.encode_polydata("brain", points, triangles, META)
    message = read(packed)
    assert message.metadata == META and np.array_equal(message.content.triangles, triangles)
    assert np.array_equal(message.content.points, points.astype(np.float32))
    content = content_of(packed)
    assert struct.unpack(">10I", content[:40]) == (50, 0, 0, 0, 0, 80, 80 * 16, 0, 0, 0)
    assert np.array_equal(struct.unpack(">150f", content[40:640]), points.astype(np.float32).ravel())
    assert struct.unpack(">8I", content[640:672]) == (3, *triangles[0], 3, *triangles[1])
    empty = read(igtl.encode_polydata("none", np.zeros((0, 3)), [])).content
    assert empty.points.shape == (0, 3) and empty.triangles.shape == (0, 3)


# ---- bad bytes ---------------------------------------------------------------------------


def test_wrong_crc_and_wrong_length():
    header, body = split(igtl.encode_string("x", "hello"))
    corrupt = body[:-1] + bytes([body[-1] ^ 1])
    with pytest.raises(igtl.ProtocolError, match="CRC"):
        igtl.check_body(header, corrupt)
    with pytest.raises(igtl.ProtocolError, match="header said"):
        igtl.check_body(header, body[:-1])


def test_cut_header_wrong_version_garbage_and_unknown_type():
    data = igtl.encode_string("x", "hello")
    with pytest.raises(igtl.ProtocolError, match="header of 57 bytes"):
        igtl.parse_header(data[:57])
    reader = igtl.Reader()
    assert reader.feed(data[:57]) == [] and reader.pending == 57  # a cut header waits for the rest
    for version in (0, 4):
        with pytest.raises(igtl.ProtocolError, match=f"version {version}"):
            igtl.parse_header(struct.pack(">H", version) + data[2:58])
    with pytest.raises(igtl.ProtocolError, match="unsupported type 'IMAGE'"):
        igtl.parse_header(frame(b"IMAGE", b"")[:58])
    for kind in (b"\xffSTRING", b"STR\0NG", b"", b"STR NG"):
        with pytest.raises(igtl.ProtocolError, match="not an ASCII name"):
            igtl.parse_header(frame(kind, b"")[:58])


def test_oversized_body_refused_from_the_header_alone():
    header = struct.pack(">H12s20sIIQQ", 2, b"POINT", b"x", 0, 0, (1 << 20) + 1, 0)
    with pytest.raises(igtl.ProtocolError, match="POINT body of 1048577 bytes is over the 1048576-byte limit"):
        igtl.parse_header(header)
    reader = igtl.Reader()
    with pytest.raises(igtl.ProtocolError, match="over the"):
        reader.feed(header + bytes(200_000))  # the body's first bytes come in the same chunk
    assert reader.pending == 0  # nothing of the body was kept
    reader = igtl.Reader()
    assert reader.feed(header[:30]) == [] and reader.pending == 30
    with pytest.raises(igtl.ProtocolError):
        reader.feed(header[30:])


def test_bad_bodies_each_say_what():
    cases = [
        (frame(b"POINT", bytes(137)), "POINT body of 137 bytes is not a whole number of 136-byte points"),
        (frame(b"TRANSFORM", bytes(44)), "TRANSFORM body of 44 bytes"),
        (frame(b"POSITION", bytes(16)), "POSITION body of 16 bytes"),
        (frame(b"STRING", struct.pack(">HH", 3, 9) + b"short"), "STRING of 9 bytes"),
        (frame(b"STRING", struct.pack(">HH", 4, 2) + b"hi"), "character set 4"),
        (frame(b"STRING", struct.pack(">HH", 3, 2) + b"\xc3\xa9"), "not valid ascii"),
        (frame(b"POLYDATA", polydata_by_hand(index=6)), "TRIANGLE_STRIPS: point index 6 for 6 points"),
        (frame(b"POLYDATA", polydata_by_hand()[:-4]), "sections end at byte"),
        (frame(b"POLYDATA", polydata_by_hand()[:30]), "shorter than its 40-byte header"),
        (frame(b"POLYDATA", struct.pack(">10I", 10**9, 0, 0, 0, 0, 0, 0, 0, 0, 0)), "does not fit"),
        (frame(b"POLYDATA", struct.pack(">10I", 0, 0, 0, 0, 0, 1, 8, 0, 0, 0) + struct.pack(">2I", 1, 0)), "index 0"),
    ]
    for data, message in cases:
        header, body = split(data)
        igtl.check_body(header, body)
        with pytest.raises(igtl.ProtocolError, match=message):
            igtl.decode(header, body)


def test_metadata_sizes_beyond_the_body():
    data = igtl.encode_point("p", ["a"], [[1.0, 2.0, 3.0]], META)
    extended, meta_head, meta_size, _ = struct.unpack(">HHII", data[58:70])
    for sizes, message in [
        ((extended, meta_head, meta_size + 200), "do not fit"),
        ((5, meta_head, meta_size), "do not fit"),
        ((extended, meta_head + 8, meta_size - 8), "does not hold"),
    ]:
        body = struct.pack(">HHII", *sizes, 0) + data[70:]
        with pytest.raises(igtl.ProtocolError, match=message):
            igtl.decode(igtl.parse_header(data[:58]), body)
    body = bytearray(data[58:])
    first_value_size = len(body) - meta_head - meta_size + 2 + 4  # in the metadata header's first entry
    body[first_value_size : first_value_size + 4] = struct.pack(">I", 4)  # "RAS" is 3 bytes
    with pytest.raises(igtl.ProtocolError, match="do not add up"):
        igtl.decode(igtl.parse_header(data[:58]), bytes(body))
    with pytest.raises(igtl.ProtocolError, match="shorter than the extended header"):
        igtl.decode(igtl.parse_header(data[:58]), data[58:66])


def test_what_cannot_be_sent_is_refused():
    with pytest.raises(igtl.ProtocolError, match="longer than 20 bytes"):
        igtl.encode_string("a_device_name_of_21ch", "x")
    with pytest.raises(igtl.ProtocolError, match="not ASCII"):
        igtl.encode_string("Gerät", "x")
    with pytest.raises(igtl.ProtocolError, match="triangle index"):
        igtl.encode_polydata("s", np.zeros((3, 3)), [[0, 1, 3]])
    with pytest.raises(igtl.ProtocolError, match="positions of shape"):
        igtl.encode_point("p", ["a", "b"], [[1.0, 2.0, 3.0]])


def test_fuzz_raises_only_protocol_error():
    """2000 seeded mutations of valid messages; in 4 of 5 the body size and CRC are made right
    again, so that the body's own checks are reached."""
    rng = np.random.default_rng(20240607)
    seeds = [
        igtl.encode_point("p", ["a", "b"], [[1.0, 2.0, 3.0], [np.nan, np.inf, 0.0]], META),
        igtl.encode_string("s", "déjà", META),
        igtl.encode_transform("t", np.eye(4), META),
        igtl.encode_position("q", [1.0, 2.0, 3.0]),
        igtl.encode_polydata("m", np.zeros((4, 3)), [[0, 1, 2], [1, 2, 3]], META),
        frame(b"POLYDATA", polydata_by_hand()),
        frame(b"POSITION", bytes(24)),
    ]
    outcomes = {"decoded": 0, "refused": 0, "waiting": 0}
    for _ in range(2000):
        data = bytearray(seeds[rng.integers(len(seeds))])
        for _ in range(rng.integers(1, 4)):
            at = int(rng.integers(len(data)))
            kind = rng.integers(5)
            if kind == 0:
                data[at] ^= 1 << int(rng.integers(8))
            elif kind == 1 and at >= 58:
                data[at : at + 4] = struct.pack(
                    ">I", int(rng.choice([0, 1, 3, 7, 0xFFFF, 0xFFFFFFFF, rng.integers(1 << 32)]))
                )
            elif kind == 2 and at >= 58:
                del data[at : at + int(rng.integers(1, 9))]
            elif kind == 3 and at >= 58:
                data[at:at] = rng.bytes(int(rng.integers(1, 9)))
            else:
                data[at] = int(rng.integers(256))
        if rng.random() < 0.8 and len(data) >= 58:  # size and CRC made right: the body's checks are reached
            data[42:58] = struct.pack(">QQ", len(data) - 58, CRC64(bytes(data[58:])))
        reader = igtl.Reader()
        try:
            messages = reader.feed(bytes(data))
            for header, body in messages:
                igtl.check_body(header, body)
                igtl.decode(header, body)
            outcomes["decoded" if messages else "waiting"] += 1
        except igtl.ProtocolError as error:
            assert str(error)
            outcomes["refused"] += 1
    assert min(outcomes.values()) > 50, outcomes  # every path exercised
