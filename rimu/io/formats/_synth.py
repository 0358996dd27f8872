"""Synthetic DataFlash logs laid out as ArduPilot writes them (tests and benchmarks): FMT messages (type 128),
``UNIT``/``MULT``/``FMTU`` unit declarations (ids, labels and multipliers as ``AP_Logger/LogStructure.h`` has them),
then IMU records (the current ``IMU`` with instance field ``I``, or the older
``IMU``/``IMU2``/``IMU3``) interleaved with an attitude message, written in blocks (constant memory).
"""

from __future__ import annotations

import os
import struct
from collections.abc import Callable
from typing import IO

import numpy as np

__all__ = ["write_dataflash"]

_IMU_COLS = "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz"
_IMU_FMT = "QBffffffIIfBBHH"
_OLD_COLS = "TimeUS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz"
_OLD_FMT = "QffffffIIfBBHH"
_STRUCT = {"Q": "Q", "B": "B", "f": "f", "d": "d", "I": "I", "H": "H", "b": "b", "Z": "64s", "N": "16s", "n": "4s", "h": "h"}


def _fmt_msg(t: int, name: str, fmt: str, cols: str) -> bytes:
    length = 3 + struct.calcsize("<" + "".join(_STRUCT[c] for c in fmt))
    return struct.pack("<BBBBB4s16s64s", 0xA3, 0x95, 128, t, length, name.encode(), fmt.encode(), cols.encode())


def write_dataflash(path: str | os.PathLike[str], n_imus: int, rate_hz: float, duration_s: float,
                    signal: Callable[[np.ndarray, int], tuple[np.ndarray, np.ndarray]] | None = None,
                    old_names: bool = False, units: bool = True, block: int = 20_000,
                    opener: Callable[..., IO[bytes]] = open, gyro_mult: str = "0", time_ms: bool = False,
                    raw_rate_hz: float | None = None) -> int:
    """Write a log of ``n_imus`` IMUs at ``rate_hz`` for ``duration_s``; returns the number of IMU records.

    ``signal(t, i) -> (gyro (N,3) rad/s, accel (N,3) m/s^2)`` of IMU i at times t (default: at rest, z up, a
    small per-IMU bias). IMU i's stamps are ``k / rate + 37 us * i`` (the instances are sampled apart).
    ``gyro_mult``: the multiplier id ``FMTU`` states for the gyro fields (ArduPilot writes ``0``, times 1); the
    values are written divided by it. ``time_ms``: the layout of logs before ArduPilot 3.3 (``IMU``/``IMU2``/
    ``IMU3`` stamped ``TimeMS`` [ms], no units declared; implies ``old_names`` and ``units=False``).
    ``raw_rate_hz``: also ArduPilot's raw messages (``INS_RAW_LOG_OPT``): ``GYR`` of every instance at that rate and
    ``ACC`` at half of it, stamped ``SampleUS`` (instance i's offset by ``11 us * i``), written after the ``IMU``
    records of the same span.
    """
    from .dataflash import MULTIPLIERS

    if time_ms:
        old_names, units = True, False
    if signal is None:
        def signal(t: np.ndarray, i: int) -> tuple[np.ndarray, np.ndarray]:
            g = np.tile([0.001 * (i + 1), -0.002, 0.0005], (len(t), 1))
            a = np.tile([0.01 * i, 0.02, 9.80665], (len(t), 1))
            return g, a
    n = int(round(duration_s * rate_hz))
    types = [(64 + i, ("IMU" if i == 0 else f"IMU{i + 1}")) for i in range(n_imus)] if old_names else [(64, "IMU")]
    tfield = ("TimeMS", "<u4") if time_ms else ("TimeUS", "<u8")
    imu_dt = np.dtype([("h0", "u1"), ("h1", "u1"), ("ty", "u1"), tfield]
                      + ([] if old_names else [("I", "u1")])
                      + [(c, "<f4") for c in ("GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ")]
                      + [("EG", "<u4"), ("EA", "<u4"), ("T", "<f4"), ("GH", "u1"), ("AH", "u1"), ("GHz", "<u2"),
                         ("AHz", "<u2")])
    att_dt = np.dtype([("h0", "u1"), ("h1", "u1"), ("ty", "u1"), ("TimeUS", "<u8")]
                      + [(c, "<f4") for c in ("Roll", "Pitch", "Yaw")])
    with opener(path, "wb") as fh:
        fh.write(_fmt_msg(128, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns"))
        fh.write(_fmt_msg(177, "UNIT", "QbZ", "TimeUS,Id,Label"))
        fh.write(_fmt_msg(178, "FMTU", "QBNN", "TimeUS,FmtType,UnitIds,MultIds"))
        fh.write(_fmt_msg(172, "MULT", "Qbd", "TimeUS,Id,Mult"))
        old_fmt, old_cols = ("I" + _OLD_FMT[1:], "TimeMS" + _OLD_COLS[6:]) if time_ms else (_OLD_FMT, _OLD_COLS)
        for t, name in types:
            fh.write(_fmt_msg(t, name, old_fmt if old_names else _IMU_FMT, old_cols if old_names else _IMU_COLS))
        fh.write(_fmt_msg(30, "ATT", "Qfff", "TimeUS,Roll,Pitch,Yaw"))
        if raw_rate_hz:
            fh.write(_fmt_msg(70, "GYR", "QBQfff", "TimeUS,I,SampleUS,GyrX,GyrY,GyrZ"))
            fh.write(_fmt_msg(71, "ACC", "QBQfff", "TimeUS,I,SampleUS,AccX,AccY,AccZ"))
        if units:
            for uid, label in (("s", "s"), ("#", "instance"), ("E", "rad/s"), ("o", "m/s/s"), ("O", "degC"),
                               ("z", "Hz"), ("-", "")):
                fh.write(struct.pack("<BBBQb64s", 0xA3, 0x95, 177, 0, ord(uid), label.encode()))
            for mid, mult in MULTIPLIERS.items():
                fh.write(struct.pack("<BBBQbd", 0xA3, 0x95, 172, 0, ord(mid), mult))
            for t, _ in types:
                ids = ("s" if old_names else "s#") + "EEEooo--O--zz"
                mults = ("F" if old_names else "F-") + 3 * gyro_mult + "000-----00"
                fh.write(struct.pack("<BBBQB16s16s", 0xA3, 0x95, 178, 0, t, ids.encode(), mults.encode()))
            if raw_rate_hz:
                for t, ids, mults in ((70, "s#sEEE", "F-F" + 3 * gyro_mult), (71, "s#sooo", "F-F000")):
                    fh.write(struct.pack("<BBBQB16s16s", 0xA3, 0x95, 178, 0, t, ids.encode(), mults.encode()))
        for k0 in range(0, n, block):
            k = np.arange(k0, min(n, k0 + block))
            m = len(k)
            recs = []
            for i in range(n_imus):
                if time_ms:
                    tu = np.round(k / rate_hz * 1e3).astype(np.uint64) * np.uint64(1000)
                else:
                    tu = np.round(k / rate_hz * 1e6).astype(np.uint64) + np.uint64(37 * i)
                g, a = signal(tu * 1e-6, i)
                g = g / MULTIPLIERS[gyro_mult]
                r = np.zeros(m, imu_dt)
                r["h0"], r["h1"] = 0xA3, 0x95
                r["ty"] = types[i][0] if old_names else 64
                r[tfield[0]] = tu // np.uint64(1000) if time_ms else tu
                if not old_names:
                    r["I"] = i
                for j, c in enumerate(("GyrX", "GyrY", "GyrZ")):
                    r[c] = g[:, j]
                for j, c in enumerate(("AccX", "AccY", "AccZ")):
                    r[c] = a[:, j]
                r["T"] = 40.0 + i
                r["GHz"], r["AHz"] = int(rate_hz), int(rate_hz)
                recs.append(r.view(np.uint8).reshape(m, -1))
            att = np.zeros(m, att_dt)
            att["h0"], att["h1"], att["ty"] = 0xA3, 0x95, 30
            att["TimeUS"] = np.round(k / rate_hz * 1e6).astype(np.uint64)
            rows = np.concatenate(recs + [att.view(np.uint8).reshape(m, -1)], axis=1)
            fh.write(rows.tobytes())
            if raw_rate_hz:
                fh.write(_raw_records(k0 / rate_hz, (k0 + m) / rate_hz, n_imus, raw_rate_hz, signal, gyro_mult))
    return n * n_imus


def _raw_records(t0: float, t1: float, n_imus: int, rate_hz: float,
                 signal: Callable[[np.ndarray, int], tuple[np.ndarray, np.ndarray]], gyro_mult: str) -> bytes:
    """``GYR`` (at ``rate_hz``) and ``ACC`` (at half of it) records of every instance sampled in ``[t0, t1)``."""
    from .dataflash import MULTIPLIERS

    dt = np.dtype([("h0", "u1"), ("h1", "u1"), ("ty", "u1"), ("TimeUS", "<u8"), ("I", "u1"), ("SampleUS", "<u8"),
                   ("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
    out = []
    for ty, r, pick, scale in ((70, rate_hz, 0, MULTIPLIERS[gyro_mult]), (71, rate_hz / 2, 1, 1.0)):
        k = np.arange(int(np.ceil(t0 * r - 1e-9)), int(np.ceil(t1 * r - 1e-9)))
        for i in range(n_imus):
            su = np.round(k / r * 1e6).astype(np.uint64) + np.uint64(11 * i)
            v = signal(su * 1e-6, i)[pick] / scale
            rec = np.zeros(len(k), dt)
            rec["h0"], rec["h1"], rec["ty"], rec["I"] = 0xA3, 0x95, ty, i
            rec["SampleUS"], rec["TimeUS"] = su, su + np.uint64(100)
            rec["x"], rec["y"], rec["z"] = v[:, 0], v[:, 1], v[:, 2]
            out.append(rec.tobytes())
    return b"".join(out)
