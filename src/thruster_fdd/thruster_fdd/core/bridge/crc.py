"""The checksums of the two wire formats (docs/protocol.md): CRC-16/CCITT-FALSE of the tfdd
bridge protocol and the CRC-8 (poly 0x07) of KISS / BLHeli_32 ESC telemetry.
"""

from __future__ import annotations

import binascii


def crc16_ccitt_false(data: bytes) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, not reflected, xorout 0).

    Parameters
    ----------
    data : bytes
        Bytes to check.

    Returns
    -------
    int
        The CRC, 0..0xFFFF (0x29B1 for ``b"123456789"``).
    """
    # binascii.crc_hqx is this exact CRC (poly 0x1021, MSB first) given init 0xFFFF.
    return binascii.crc_hqx(data, 0xFFFF)


def _crc8_table(poly: int) -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ poly) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return tuple(table)


_CRC8_TABLE = _crc8_table(0x07)


def crc8_kiss(data: bytes) -> int:
    """CRC-8 of KISS / BLHeli_32 telemetry (poly 0x07, init 0, MSB first: CRC-8/SMBUS).

    Equal to the ``get_crc8`` / ``update_crc8`` pair of the KISS ESC telemetry documentation and
    Betaflight.

    Parameters
    ----------
    data : bytes
        Bytes to check.

    Returns
    -------
    int
        The CRC, 0..0xFF (0xF4 for ``b"123456789"``).
    """
    crc = 0
    for byte in data:
        crc = _CRC8_TABLE[crc ^ byte]
    return crc
