"""Checksums of CAN frames and serial packets, scalar and vectorised over many frames.

* ``crc8_sae_j1850``: CRC-8/SAE-J1850 (poly 0x1D, init 0xFF, xorout 0xFF), the CRC of AUTOSAR E2E profiles 1
  and 2 and of many automotive sensors. Check value (CRC of ``b"123456789"``) 0x4B.
* ``crc8_autosar``: CRC-8/AUTOSAR (poly 0x2F, init 0xFF, xorout 0xFF). Check value 0xDF.
* ``xor8`` and ``sum8``: byte-wise XOR and sum modulo 256 (weak; for simple devices).
* ``crc16_ccitt``: CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, xorout 0), the serial framing's
  CRC, computed in C by :func:`binascii.crc_hqx`. Check value 0x29B1.

>>> hex(crc8(b"123456789", "crc8_sae_j1850")), hex(crc8(b"123456789", "crc8_autosar")), hex(crc16_ccitt(b"123456789"))
('0x4b', '0xdf', '0x29b1')
"""

from __future__ import annotations

import binascii

import numpy as np

from ..errors import FrameError

__all__ = ["CHECKSUMS", "crc8", "crc8_columns", "crc16_ccitt", "crc16_ccitt_rows"]


def _crc8_table(poly: int) -> np.ndarray:
    tab = np.zeros(256, dtype=np.uint8)
    for b in range(256):
        c = b
        for _ in range(8):
            c = ((c << 1) ^ poly) & 0xFF if c & 0x80 else (c << 1) & 0xFF
        tab[b] = c
    return tab


#: algorithm -> (table or None, init, xorout)
CHECKSUMS: dict[str, tuple[np.ndarray | None, int, int]] = {
    "crc8_sae_j1850": (_crc8_table(0x1D), 0xFF, 0xFF),
    "crc8_autosar": (_crc8_table(0x2F), 0xFF, 0xFF),
    "xor8": (None, 0x00, 0x00),
    "sum8": (None, 0x00, 0x00),
}


def _algo(name: str) -> tuple[np.ndarray | None, int, int]:
    try:
        return CHECKSUMS[name]
    except KeyError:
        raise FrameError(f"unknown checksum algorithm {name!r}; known: {sorted(CHECKSUMS)}") from None


def crc8(data: bytes, algorithm: str = "crc8_sae_j1850") -> int:
    """Checksum of one byte string."""
    return int(crc8_columns(np.frombuffer(bytes(data), dtype=np.uint8)[None, :], algorithm)[0])


def crc8_columns(cols: np.ndarray, algorithm: str = "crc8_sae_j1850") -> np.ndarray:
    """Checksum of every row of a (N, k) uint8 array, vectorised over rows (one table look-up per column)."""
    tab, init, xorout = _algo(algorithm)
    cols = np.asarray(cols, dtype=np.uint8)
    if algorithm == "xor8":
        return np.bitwise_xor.reduce(cols, axis=1).astype(np.uint8) if cols.shape[1] else np.zeros(len(cols), np.uint8)
    if algorithm == "sum8":
        return (cols.astype(np.uint64).sum(axis=1) & 0xFF).astype(np.uint8)
    c = np.full(cols.shape[0], init, dtype=np.uint8)
    for j in range(cols.shape[1]):
        c = tab[c ^ cols[:, j]]
    return c ^ np.uint8(xorout)


def crc16_ccitt(data: bytes | bytearray | memoryview, init: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE of ``data``."""
    return binascii.crc_hqx(data, init)


def _crc16_table() -> np.ndarray:
    tab = np.zeros(256, dtype=np.uint16)
    for b in range(256):
        c = b << 8
        for _ in range(8):
            c = ((c << 1) ^ 0x1021) & 0xFFFF if c & 0x8000 else (c << 1) & 0xFFFF
        tab[b] = c
    return tab


_CRC16_TABLE = _crc16_table()


def crc16_ccitt_rows(rows: np.ndarray, init: int = 0xFFFF) -> np.ndarray:
    """CRC-16/CCITT-FALSE of every row of a (K, m) uint8 array, vectorised over rows (one table look-up per
    column): the check of many equal-length frames at once.

    >>> rows = np.frombuffer(b"123456789" * 2, dtype=np.uint8).reshape(2, 9)
    >>> [hex(int(c)) for c in crc16_ccitt_rows(rows)]
    ['0x29b1', '0x29b1']
    """
    rows = np.asarray(rows, dtype=np.uint8)
    c = np.full(rows.shape[0], init, dtype=np.uint16)
    tab = _CRC16_TABLE
    for j in range(rows.shape[1]):
        c = (c << np.uint16(8)) ^ tab[(c >> np.uint16(8)) ^ rows[:, j]]
    return c
