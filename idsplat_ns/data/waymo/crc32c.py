"""CRC-32C (Castagnoli), as TFRecord framing uses it, from the google-crc32c package.

google-crc32c is TensorFlow's own checksum library without TensorFlow (C, ~2 GB/s here, against
~50 MB/s for the numpy implementation it replaced; both agreed on every length tried).
"""

from __future__ import annotations

import google_crc32c


def crc32c(data: bytes | bytearray | memoryview) -> int:
    """CRC-32C of ``data`` (init 0xFFFFFFFF, final xor 0xFFFFFFFF); crc32c(b"123456789") == 0xE3069283."""
    return int(google_crc32c.value(bytes(data) if isinstance(data, memoryview) else data))


def masked_crc32c(data: bytes | bytearray | memoryview) -> int:
    """TFRecord's masked CRC: rotate right by 15 bits and add 0xA282EAD8 (mod 2**32)."""
    crc = crc32c(data)
    return (((crc >> 15) | (crc << 17)) + 0xA282EAD8) & 0xFFFFFFFF
