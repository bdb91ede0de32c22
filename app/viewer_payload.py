"""The viewer payload of a frame: an uncompressed `.npz` (a ZIP whose `.npy` members are stored) of

    points     (N, 3) float32  lidar frame, metres
    intensity  (N,)   float32  in [0, 1]
    segment    (N,)   int32    local segment id, -1 = ground / none
    track      (N,)   int32    database track id, 0 = none (int64 once ids pass 2**31)
    ground     (N,)   bool     the ground estimate (the points a ground region can label)

`payload_from_artifact` builds it from a frame artifact (app/artifacts.py) without decoding what it
does not change: the artifact's stored members (points, intensity) are copied byte for byte with
the CRC-32 its ZIP directory already holds, segment and ground are inflated (their CRCs are in the
directory too), and only track is narrowed to int32 and checksummed. Every member is written once,
straight into one buffer, returned as a read-only memoryview that Starlette sends without a copy.
`frame_payload` builds the same archive from arrays; it is the fallback for an artifact whose
layout the fast path does not expect.
"""

from __future__ import annotations

import io
import struct
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import numpy as np

PAYLOAD_ARRAYS = ("points", "intensity", "segment", "track", "ground")

# ZIP records (as zipfile's structFileHeader, structCentralDir, structEndArchive)
_LOCAL = struct.Struct("<4s2B4HL2L2H")
_CENTRAL = struct.Struct("<4s4B4HL2L5H2L")
_END = struct.Struct("<4s4H2LH")
_DOS_DATE = (1 << 5) | 1  # 1980-01-01 00:00, as the artifacts are written
_INT32_MAX = int(np.iinfo(np.int32).max)


def frame_payload(arrays: dict[str, np.ndarray]) -> bytes:
    """The payload from the arrays of `PAYLOAD_ARRAYS` (track: any int dtype, narrowed to int32
    while the ids fit)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_STORED) as zf:
        for name in PAYLOAD_ARRAYS:
            arr = np.ascontiguousarray(arrays[name])
            if name == "track" and (len(arr) == 0 or int(arr.max()) <= _INT32_MAX):
                arr = arr.astype(np.int32)  # 4 bytes a point while database ids fit
            with zf.open(f"{name}.npy", "w", force_zip64=True) as fh:
                np.lib.format.write_array(fh, arr, allow_pickle=False)
    return buf.getvalue()


@dataclass(frozen=True)
class _Member:
    """One `.npy` member of the payload, `size` bytes: copied from the artifact file at
    `file_offset`, or `data`, or `header` followed by `values` (int64) narrowed to int32.
    `crc` None = checksummed once written."""

    name: bytes
    size: int
    crc: int | None
    file_offset: int | None = None
    data: bytes | None = None
    header: bytes = b""
    values: np.ndarray | None = None


def payload_from_artifact(path: Path) -> memoryview | None:
    """The payload of the frame artifact at `path`; None when its layout is not the expected one
    (then build it with `frame_payload`). A missing file raises FileNotFoundError."""
    with open(path, "rb", buffering=0) as f:
        try:
            directory = zipfile.ZipFile(f)
            infos = [directory.getinfo(f"{name}.npy") for name in PAYLOAD_ARRAYS]
        except (zipfile.BadZipFile, KeyError):
            return None
        members = []
        for info in infos:
            member = _member(f, info)
            if member is None:
                return None
            members.append(member)
        return _assemble(f, members)


def _member(f: BinaryIO, info: zipfile.ZipInfo) -> _Member | None:
    f.seek(info.header_offset)
    local = f.read(_LOCAL.size)
    if len(local) != _LOCAL.size or local[:4] != b"PK\x03\x04":
        return None
    _, _, _, _, _, _, _, _, _, _, name_len, extra_len = _LOCAL.unpack(local)
    offset = info.header_offset + _LOCAL.size + name_len + extra_len
    name = info.filename.encode()
    is_track = info.filename == "track.npy"
    if info.compress_type == zipfile.ZIP_STORED and not is_track:
        return _Member(name, info.file_size, info.CRC, file_offset=offset)
    f.seek(offset)
    if info.compress_type == zipfile.ZIP_STORED:
        data = f.read(info.file_size)
    elif info.compress_type == zipfile.ZIP_DEFLATED:
        data = zlib.decompress(f.read(info.compress_size), -zlib.MAX_WBITS, info.file_size)
    else:
        return None
    if len(data) != info.file_size:
        return None
    return _track_member(name, data, info.CRC) if is_track else _Member(name, len(data), info.CRC, data=data)


def _track_member(name: bytes, npy: bytes, crc: int) -> _Member | None:
    """The track member: int64 ids narrowed to int32 while they fit, else as they are (int64 past
    2**31, or int32 already); None for any other array (then `frame_payload` decides)."""
    fh = io.BytesIO(npy)
    version = np.lib.format.read_magic(fh)
    read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
    shape, fortran_order, dtype = read_header(fh)
    if fortran_order or len(shape) != 1 or dtype not in (np.dtype("<i8"), np.dtype("<i4")):
        return None
    values = np.frombuffer(npy, dtype, count=shape[0], offset=fh.tell())
    if dtype == np.dtype("<i4") or (len(values) and int(values.max()) > _INT32_MAX):
        return _Member(name, len(npy), crc, data=npy)
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        header, {"descr": np.lib.format.dtype_to_descr(np.dtype("<i4")), "fortran_order": False, "shape": shape}
    )
    head = header.getvalue()
    return _Member(name, len(head) + 4 * len(values), None, header=head, values=values)


def _assemble(f: BinaryIO, members: list[_Member]) -> memoryview | None:
    """Write the ZIP (local header + data per member, central directory, end record) into one buffer."""
    total = sum(_LOCAL.size + _CENTRAL.size + 2 * len(m.name) + m.size for m in members) + _END.size
    if total >= 2**32:
        return None  # would need ZIP64 records
    buf = np.empty(total, np.uint8)
    out = memoryview(buf)
    pos = 0
    central = []
    for m in members:
        start = pos + _LOCAL.size + len(m.name)
        body = out[start : start + m.size]
        if m.file_offset is not None:
            f.seek(m.file_offset)
            done = 0
            while done < m.size:
                n = f.readinto(body[done:])
                if not n:
                    raise zipfile.BadZipFile(f"{f.name}: member {m.name.decode()} is truncated")
                done += n
            crc = m.crc
        elif m.data is not None:
            body[:] = m.data
            crc = m.crc
        else:
            assert m.values is not None
            body[: len(m.header)] = m.header
            np.copyto(buf[start + len(m.header) : start + m.size].view(np.int32), m.values, casting="same_kind")
            crc = zlib.crc32(body)
        assert crc is not None
        out[pos : pos + _LOCAL.size] = _LOCAL.pack(
            b"PK\x03\x04", 20, 0, 0, zipfile.ZIP_STORED, 0, _DOS_DATE, crc, m.size, m.size, len(m.name), 0
        )
        out[pos + _LOCAL.size : start] = m.name
        central.append(
            _CENTRAL.pack(
                b"PK\x01\x02", 20, 3, 20, 0, 0, zipfile.ZIP_STORED, 0, _DOS_DATE, crc, m.size, m.size,
                len(m.name), 0, 0, 0, 0, 0, pos,
            )
            + m.name
        )
        pos = start + m.size
    directory = b"".join(central)
    out[pos : pos + len(directory)] = directory
    out[pos + len(directory) :] = _END.pack(b"PK\x05\x06", 0, 0, len(members), len(members), len(directory), pos, 0)
    return out.toreadonly()
