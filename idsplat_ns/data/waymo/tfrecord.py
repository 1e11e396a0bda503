"""TFRecord files without TensorFlow: streaming reads with CRC checks, and writing (tests, re-framing).

Each record is framed as::

    uint64 length (little endian) | uint32 masked_crc32c(length bytes) | data[length] | uint32 masked_crc32c(data)

Reading streams one record at a time from an open file, so memory holds one record (a Waymo
frame is 2-10 MB) rather than the ~1 GB segment. Every problem is an :class:`IDSplatError` whose
one-line message names the file and the byte offset of the record.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, Iterable, Iterator, Optional

from idsplat_ns.data.waymo.crc32c import masked_crc32c
from idsplat_ns.errors import IDSplatError

_HEADER = struct.Struct("<QI")
_FOOTER = struct.Struct("<I")
# A Waymo frame is at most tens of MB; a length beyond this means the file is not a TFRecord.
MAX_RECORD_BYTES = 1 << 30


@dataclass(frozen=True)
class RecordRef:
    """Where one record lies in a TFRecord file."""

    index: int
    """Record number, from 0."""
    offset: int
    """Byte offset of the record's header in the file."""
    length: int
    """Length of the record's data in bytes."""


def _read_header(f: BinaryIO, path: Path, index: int, offset: int) -> Optional[int]:
    """Length of the record starting at ``offset``; None at a clean end of file."""
    head = f.read(_HEADER.size)
    if not head:
        return None
    where = f"{path}: record {index} at byte offset {offset}"
    if len(head) < _HEADER.size:
        raise IDSplatError(f"{where}: truncated header ({len(head)} of 12 bytes); the file is cut short, re-download it")
    length, length_crc = _HEADER.unpack(head)
    if masked_crc32c(head[:8]) != length_crc:
        raise IDSplatError(
            f"{where}: length checksum mismatch; this is not a TFRecord file or it is corrupt, re-download it"
        )
    if length > MAX_RECORD_BYTES:
        raise IDSplatError(f"{where}: record length {length} is implausible; the file is corrupt, re-download it")
    return length


def iter_record_refs(path: str | Path) -> Iterator[RecordRef]:
    """Walk a TFRecord file's framing (headers only, seeking over data) and yield each record's place.

    Length checksums are verified; data checksums are not (see :func:`iter_records` for that).
    """
    path = Path(path)
    size = _file_size(path)
    with open(path, "rb") as f:
        index, offset = 0, 0
        while True:
            length = _read_header(f, path, index, offset)
            if length is None:
                return
            end = offset + _HEADER.size + length + _FOOTER.size
            if end > size:
                raise IDSplatError(
                    f"{path}: record {index} at byte offset {offset}: truncated (needs {end} bytes, file has {size}); "
                    "the file is cut short, re-download it"
                )
            yield RecordRef(index=index, offset=offset, length=length)
            f.seek(end)
            index, offset = index + 1, end


def iter_records(
    path: str | Path, start: int = 0, end: Optional[int] = None, verify: bool = True
) -> Iterator[tuple[RecordRef, bytes]]:
    """Yield ``(ref, data)`` for records ``start <= index < end`` (``end=None``: to the last one).

    Records before ``start`` are skipped by seeking (their data is not read or checked); reading
    stops after ``end - 1`` so later records are never touched. ``verify`` checks the data CRC.
    """
    path = Path(path)
    size = _file_size(path)
    with open(path, "rb") as f:
        index, offset = 0, 0
        while end is None or index < end:
            length = _read_header(f, path, index, offset)
            if length is None:
                return
            where = f"{path}: record {index} at byte offset {offset}"
            record_end = offset + _HEADER.size + length + _FOOTER.size
            if record_end > size:
                raise IDSplatError(
                    f"{where}: truncated (needs {record_end} bytes, file has {size}); the file is cut short, re-download it"
                )
            if index < start:
                f.seek(record_end)
            else:
                data = f.read(length)
                (data_crc,) = _FOOTER.unpack(f.read(_FOOTER.size))
                if verify and masked_crc32c(data) != data_crc:
                    raise IDSplatError(f"{where}: data checksum mismatch; the file is corrupt, re-download it")
                yield RecordRef(index=index, offset=offset, length=length), data
            index, offset = index + 1, record_end


def frame_record(data: bytes) -> bytes:
    """One record's bytes in TFRecord framing."""
    length = struct.pack("<Q", len(data))
    return length + struct.pack("<I", masked_crc32c(length)) + data + struct.pack("<I", masked_crc32c(data))


def write_records(path: str | Path, records: Iterable[bytes]) -> int:
    """Write records to a TFRecord file (via a temporary name, then renamed). Returns the count."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    count = 0
    with open(tmp, "wb") as f:
        for data in records:
            f.write(frame_record(data))
            count += 1
    tmp.replace(path)
    return count


def _file_size(path: Path) -> int:
    if not path.is_file():
        raise IDSplatError(f"{path}: no such file; pass the path of a Waymo segment-*.tfrecord file")
    return path.stat().st_size
