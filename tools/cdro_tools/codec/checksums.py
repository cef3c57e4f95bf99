"""CRC-16/CCITT-FALSE and CRC-32/ISO-HDLC, as in common/include/cdro/crc.h."""
from __future__ import annotations

import zlib

CRC16_INIT = 0xFFFF


def _crc16_table() -> list[int]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
        table.append(crc)
    return table


_CRC16_TABLE = _crc16_table()


def crc16(data: bytes, crc: int = CRC16_INIT) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF); pass crc to continue incrementally."""
    for byte in data:
        crc = ((crc << 8) & 0xFFFF) ^ _CRC16_TABLE[(crc >> 8) ^ byte]
    return crc


def crc32(data: bytes, crc: int = 0) -> int:
    """CRC-32/ISO-HDLC (zlib's); pass the previous result to continue incrementally."""
    return zlib.crc32(data, crc) & 0xFFFFFFFF
