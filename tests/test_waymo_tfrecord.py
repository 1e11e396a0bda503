"""TFRecord framing, CRC-32C and the one-line errors on bad files."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from idsplat_ns.data.waymo import load_segment
from idsplat_ns.data.waymo.crc32c import crc32c, masked_crc32c
from idsplat_ns.data.waymo.tfrecord import frame_record, iter_record_refs, iter_records, write_records
from idsplat_ns.errors import IDSplatError

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "waymo"
FRAME = DATA / "pvps_data_one_frame.tfrecord"
needs_frame = pytest.mark.skipif(not FRAME.is_file(), reason=f"real Waymo frame not found at {FRAME}")


def _crc32c_bitwise(data: bytes) -> int:
    """Reference: the bit-at-a-time definition (reflected Castagnoli polynomial)."""
    crc = 0xFFFFFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ (0x82F63B78 if crc & 1 else 0)
    return crc ^ 0xFFFFFFFF


def test_crc32c_known_vectors_and_bitwise_reference():
    assert crc32c(b"123456789") == 0xE3069283  # the standard check value
    assert crc32c(b"") == 0
    assert crc32c(bytes(32)) == 0x8A9136AA  # RFC 3720 B.4: 32 bytes of zeros
    rng = np.random.default_rng(1)
    for n in (1, 1023, 1024, 4096 + 17, 20000):  # scalar path, lane path and tails
        data = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        assert crc32c(data) == _crc32c_bitwise(data), n


@needs_frame
def test_masked_crc_matches_the_checksums_tensorflow_wrote():
    # A TFRecord is [length u64][masked crc of the length u32][data][masked crc of the data u32];
    # the real frame was written by TensorFlow's own writer.
    raw = FRAME.read_bytes()
    (length,) = struct.unpack("<Q", raw[:8])
    assert masked_crc32c(raw[:8]) == struct.unpack("<I", raw[8:12])[0]
    assert masked_crc32c(raw[12 : 12 + length]) == struct.unpack("<I", raw[12 + length : 16 + length])[0]


def test_round_trip_offsets_and_seeking(tmp_path):
    recs = [bytes([i]) * (100 * i + 1) for i in range(5)]
    path = tmp_path / "r.tfrecord"
    assert write_records(path, recs) == 5
    refs = list(iter_record_refs(path))
    assert [r.length for r in refs] == [len(r) for r in recs]
    assert refs[0].offset == 0 and refs[1].offset == 16 + len(recs[0])
    got = list(iter_records(path, start=2, end=4))
    assert [r.index for r, _ in got] == [2, 3] and [d for _, d in got] == recs[2:4]
    assert not (tmp_path / "r.tfrecord.tmp").exists()


@needs_frame
def test_real_frame_framing_checks_out():
    (ref, data), = list(iter_records(FRAME))
    assert ref.offset == 0 and ref.length == FRAME.stat().st_size - 16 == len(data)


def _bad_copy(tmp_path: Path, edit) -> Path:
    data = bytearray(frame_record(b"x" * 5000) + frame_record(b"y" * 3000))
    data = edit(data)
    path = tmp_path / "bad.tfrecord"
    path.write_bytes(bytes(data))
    return path


def _one_line_error(path: Path) -> str:
    with pytest.raises(IDSplatError) as info:
        list(iter_records(path))
    msg = str(info.value)
    assert "\n" not in msg and str(path) in msg
    return msg


def test_truncated_file(tmp_path):
    msg = _one_line_error(_bad_copy(tmp_path, lambda d: d[:-100]))
    assert "record 1 at byte offset 5016" in msg and "truncated" in msg


def test_truncated_header(tmp_path):
    msg = _one_line_error(_bad_copy(tmp_path, lambda d: d[: 5016 + 5]))
    assert "record 1 at byte offset 5016" in msg and "truncated header" in msg


def test_flipped_byte_is_a_crc_mismatch(tmp_path):
    def flip(d):
        d[16 + 5000 + 100] ^= 0x01  # inside record 1's data
        return d

    msg = _one_line_error(_bad_copy(tmp_path, flip))
    assert "record 1 at byte offset 5016" in msg and "data checksum mismatch" in msg


def test_flipped_length_byte(tmp_path):
    def flip(d):
        d[2] ^= 0x40
        return d

    assert "length checksum mismatch" in _one_line_error(_bad_copy(tmp_path, flip))


def test_not_a_tfrecord(tmp_path):
    path = tmp_path / "notes.tfrecord"
    path.write_text("this is a text file, not a TFRecord at all\n" * 10)
    assert "record 0 at byte offset 0" in _one_line_error(path)


def test_valid_framing_but_not_a_frame(tmp_path):
    path = tmp_path / "other.tfrecord"
    write_records(path, [struct.pack("<d", 1.5) * 4])
    with pytest.raises(IDSplatError) as info:
        load_segment(path)
    assert str(path) in str(info.value) and "byte offset 0" in str(info.value)


def test_missing_file(tmp_path):
    with pytest.raises(IDSplatError, match="no such file"):
        load_segment(tmp_path / "absent.tfrecord")
