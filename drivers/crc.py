"""CRC-32/MPEG-2 (poly 0x04C11DB7, init 0xFFFFFFFF, not reflected, xorout 0), scalar and vectorised.

zlib.crc32 is the reflected variant and does not match, hence this module.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

POLY = 0x04C11DB7
INIT = 0xFFFFFFFF


def _byte_table() -> np.ndarray:
    table = np.zeros(256, dtype=np.uint32)
    for i in range(256):
        c = i << 24
        for _ in range(8):
            c = ((c << 1) ^ POLY) if c & 0x80000000 else (c << 1)
            c &= 0xFFFFFFFF
        table[i] = c
    return table


TABLE = _byte_table()
_TABLE_LIST = [int(v) for v in TABLE]
_U8 = np.uint32(8)
_U24 = np.uint32(24)


def crc32_mpeg2(data: bytes | bytearray | memoryview) -> int:
    """CRC-32/MPEG-2 of ``data`` (scalar, for single frames and tests)."""
    crc = INIT
    table = _TABLE_LIST
    for b in bytes(data):
        crc = ((crc << 8) & 0xFFFFFFFF) ^ table[(crc >> 24) ^ b]
    return crc


def crc32_mpeg2_rows(rows: np.ndarray) -> np.ndarray:
    """CRC of every row of a (K, M) uint8 array, one byte column at a time across all rows."""
    rows = np.asarray(rows, dtype=np.uint8)
    crc = np.full(rows.shape[0], INIT, dtype=np.uint32)
    for j in range(rows.shape[1]):
        crc = (crc << _U8) ^ TABLE[(crc >> _U24) ^ rows[:, j]]
    return crc


def _advance_zero_bytes(reg: np.ndarray, nbytes: int) -> np.ndarray:
    """Registers after feeding ``nbytes`` zero bytes (the CRC is linear, so this shifts contributions)."""
    reg = reg.astype(np.uint32)
    for _ in range(nbytes):
        reg = (reg << _U8) ^ TABLE[reg >> _U24]
    return reg


@lru_cache(maxsize=16)
def _residue_tables(length: int) -> tuple[np.ndarray, int, int]:
    """Per-position lookup tables for a whole frame of ``length`` bytes, CRC field included.

    For a non-reflected CRC with xorout 0, running the register over message + CRC (big-endian)
    leaves 0. The register is affine in the input bits, so it is the XOR of one table entry per
    input position plus the contribution of the init value. Those lookups are independent, so
    numpy can do them column by column over all frames at once. Even lengths use 16-bit words
    (half the lookups, 256 KiB per table, one table hot at a time); odd lengths use bytes.
    """
    const = int(_advance_zero_bytes(np.array([INIT], dtype=np.uint32), length)[0])
    if length % 2 == 0:
        v = np.arange(65536, dtype=np.uint32)
        hi, lo = v >> _U8, v & np.uint32(0xFF)
        reg = TABLE[hi]
        reg = (reg << _U8) ^ TABLE[(reg >> _U24) ^ lo]
        words = length // 2
        tables = np.empty((words, 65536), dtype=np.uint32)
        for j in range(words - 1, -1, -1):
            tables[j] = reg
            reg = _advance_zero_bytes(reg, 2)
        return tables, const, 2
    reg = TABLE.copy()
    tables = np.empty((length, 256), dtype=np.uint32)
    for j in range(length - 1, -1, -1):
        tables[j] = reg
        reg = _advance_zero_bytes(reg, 1)
    return tables, const, 1


def frames_crc_ok(rows: np.ndarray) -> np.ndarray:
    """Boolean mask: which rows of a (K, L) uint8 array end in a correct big-endian CRC-32/MPEG-2."""
    rows = np.ascontiguousarray(rows, dtype=np.uint8)
    k, length = rows.shape
    tables, const, width = _residue_tables(length)
    acc = np.full(k, const, dtype=np.uint32)
    cols = rows.view(">u2") if width == 2 else rows
    for j in range(tables.shape[0]):
        acc ^= tables[j][cols[:, j]]
    return acc == 0
