"""COBS, as in common/include/cdro/cobs.h (no trailing 0x01 after a final full block)."""
from __future__ import annotations


class CobsError(ValueError):
    """The bytes are not a valid COBS encoding."""


def max_encoded_size(length: int) -> int:
    return length + length // 254 + 1


def cobs_encode(data: bytes) -> bytes:
    out = bytearray([0])
    code_index = 0
    code = 1
    for index, byte in enumerate(data):
        if byte == 0:
            out[code_index] = code
            code = 1
            code_index = len(out)
            out.append(0)
            continue
        out.append(byte)
        code += 1
        if code == 0xFF:
            out[code_index] = code
            code = 1
            if index + 1 == len(data):
                return bytes(out)  # a full block ends the input: no further code byte
            code_index = len(out)
            out.append(0)
    out[code_index] = code
    return bytes(out)


def cobs_decode(data: bytes) -> bytes:
    if not data:
        raise CobsError("empty chunk")
    out = bytearray()
    index = 0
    while index < len(data):
        code = data[index]
        if code == 0:
            raise CobsError(f"zero byte at offset {index}")
        end = index + code
        if end > len(data):
            raise CobsError(f"code 0x{code:02X} at offset {index} runs past the end")
        block = data[index + 1:end]
        if 0 in block:
            raise CobsError("zero byte inside a block")
        out += block
        index = end
        if code != 0xFF and index < len(data):
            out.append(0)
    return bytes(out)
