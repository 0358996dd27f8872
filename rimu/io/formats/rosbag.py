"""ROS 1 bags, ROS 2 bags (sqlite3 or MCAP storage) and bare MCAP files (without the bag folder's
``metadata.yaml``; rosbags, extra ``logs``): ``sensor_msgs/Imu`` messages, one IMU per topic.

Each topic of type ``sensor_msgs/msg/Imu`` (ROS 1: ``sensor_msgs/Imu``) is one IMU, named after the topic
(``/imu0/data`` -> ``imu0_data``): ``angular_velocity`` [rad/s], ``linear_acceleration`` [m/s^2] (SI by the
message's definition, REP 103; ``meta["units_from"]`` says so), time ``header.stamp`` [s] (the bag's receive time
where the stamp is zero), axes: the ``header.frame_id`` each topic states (``meta["frames"]``, per IMU). Messages are read in bag order and handed on in pieces (:func:`iter_chunks`): a long
bag never has to fit in memory. Rejected, counted per IMU: ``nonfinite``, ``time_not_increasing``.

>>> sniff("run.bag", b"#ROSBAG V2.0\\n"), sniff("run.mcap", b"\\x89MCAP0\\r\\n")
(True, True)
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import nullcontext
from pathlib import Path
from typing import Any

import numpy as np

from ...errors import SessionFormatError
from ..multiimu import ImuStream, MultiImuRecording
from ._join import join_chunks
from ._open import local_file, plain_name

__all__ = ["EXTRA", "NAME", "iter_chunks", "read", "sniff"]

NAME = "rosbag"
EXTRA = "logs"
IMU_TYPES = ("sensor_msgs/msg/Imu", "sensor_msgs/Imu")


def sniff(name: str, head: bytes) -> bool:
    """ROS 1 bag (``#ROSBAG V2.0``), MCAP (magic), a ROS 2 ``.db3`` (SQLite) or a ROS 2 bag folder."""
    if head.startswith(b"#ROSBAG V2.0") or head.startswith(b"\x89MCAP0\r\n"):
        return True
    if head.startswith(b"SQLite format 3\x00") and name.endswith(".db3"):
        return True
    p = Path(name)
    return p.is_dir() and (p / "metadata.yaml").exists()


def _bag_path(p: Path) -> Path:
    """What rosbags opens: a ROS 1 file, or a ROS 2 bag folder (the folder of a .db3/.mcap with metadata.yaml)."""
    if p.is_file() and p.suffix in (".db3", ".mcap") and (p.parent / "metadata.yaml").exists():
        return p.parent
    return p


def _name(topic: str) -> str:
    return topic.strip("/").replace("/", "_") or "imu"


def iter_chunks(path: str | os.PathLike[str], chunk: int = 100_000, topics: list[str] | None = None,
                **options: Any) -> Iterator[MultiImuRecording]:
    """The IMUs of the bag in pieces of at most ``chunk`` messages; the last piece's ``meta`` holds the counts."""
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise ImportError("reading ROS bags needs rosbags: pip install 'rimu[logs]'", name="rosbags") from None
    p = Path(path)
    store = get_typestore(Stores.ROS2_HUMBLE)
    if p.is_file() and Path(plain_name(p)).suffix == ".mcap" and not (p.parent / "metadata.yaml").exists():
        with local_file(p, ".mcap") as lp:  # compressed: decompressed to a temporary file first
            yield from _iter_bare_mcap(p, Path(lp), chunk, topics, store)
        return
    with local_file(p, ".bag") if p.is_file() and p.suffix not in (".db3", ".mcap") else nullcontext(p) as lp:
        yield from _iter_bag(p, Path(lp), chunk, topics, AnyReader, store)


def _iter_bare_mcap(p: Path, lp: Path, chunk: int, topics: list[str] | None, store: Any
                    ) -> Iterator[MultiImuRecording]:
    """An MCAP file alone (no ``metadata.yaml``: copied out of its bag folder, or written by another MCAP writer):
    channels and schemas from the file itself (rosbags' MCAP storage reader), messages decoded by their encoding
    (``cdr`` or ``ros1``) with the ROS 2 type store."""
    from rosbags.rosbag2.storage_mcap import McapReader

    reader = McapReader(lp)
    try:
        reader.open()
    except Exception as exc:  # rosbags' errors have no common base with OSError
        raise SessionFormatError(f"{p}: not a readable MCAP file ({type(exc).__name__}: {str(exc)[:120]}); give the "
                                 "file as recorded, or its ROS 2 bag folder (with metadata.yaml)") from None
    try:
        conns = _imu_connections(p, reader.connections, topics, "channel in the MCAP file")

        def decode(c: Any, raw: bytes) -> Any:
            fmt = getattr(c.ext, "serialization_format", "cdr")
            msgtype = "sensor_msgs/msg/Imu"
            return store.deserialize_ros1(raw, msgtype) if fmt == "ros1" else store.deserialize_cdr(raw, msgtype)

        yield from _collect(p, ((c.topic, ts, decode(c, raw)) for c, ts, raw in reader.messages(conns)), chunk)
    except SessionFormatError:
        raise
    except Exception as exc:
        raise SessionFormatError(f"{p}: a message could not be read ({type(exc).__name__}: {str(exc)[:120]}); the "
                                 "file may be truncated: recover it (mcap recover)") from None
    finally:
        reader.close()


def _imu_connections(p: Path, connections: Any, topics: list[str] | None, where: str) -> list[Any]:
    """The ``sensor_msgs/Imu`` connections (of ``topics`` when given), or the refusal naming what the file holds."""
    conns = [c for c in connections if c.msgtype in IMU_TYPES and (topics is None or c.topic in topics)]
    if not conns:
        found = sorted({f"{c.topic} ({c.msgtype})" for c in connections})[:20]
        raise SessionFormatError(f"{p}: no sensor_msgs/Imu {where}; it holds {found}")
    return conns


def _iter_bag(p: Path, lp: Path, chunk: int, topics: list[str] | None, AnyReader: Any, store: Any
              ) -> Iterator[MultiImuRecording]:
    try:
        reader = AnyReader([_bag_path(lp)], default_typestore=store)
        reader.open()
    except Exception as exc:  # rosbags' errors have no common base with OSError
        raise SessionFormatError(f"{p}: not a readable ROS bag ({type(exc).__name__}: {str(exc)[:120]}); give the "
                                 "ROS 1 .bag file or the ROS 2 bag folder (with metadata.yaml)") from None
    try:
        conns = _imu_connections(p, reader.connections, topics, "topic in the bag")
        yield from _collect(p, ((c.topic, ts, reader.deserialize(raw, c.msgtype))
                                for c, ts, raw in reader.messages(connections=conns)), chunk)
    except SessionFormatError:
        raise
    except Exception as exc:
        raise SessionFormatError(f"{p}: a message could not be read ({type(exc).__name__}: {str(exc)[:120]}); the "
                                 "bag may be truncated: reindex it (rosbag reindex / ros2 bag reindex)") from None
    finally:
        reader.close()


def _collect(p: Path, msgs: Iterator[tuple[str, int, Any]], chunk: int) -> Iterator[MultiImuRecording]:
    last: dict[str, float] = {}
    rejected: dict[str, dict[str, int]] = {}
    buf: dict[str, list[list[float]]] = {}
    frames: dict[str, str] = {}
    count = 0

    def flush(final: bool) -> MultiImuRecording:
        units = []
        for topic, rows in buf.items():
            name = _name(topic)
            a = np.array(rows, float).reshape(-1, 7)
            units.append(ImuStream(name, a[:, 0], a[:, 1:4], a[:, 4:7]))
        buf.clear()
        meta: dict[str, Any] = {"format": NAME, "source": str(p)}
        if final:
            meta.update({"rejected": {_name(k): v for k, v in rejected.items()}, "records": count,
                         "frames": {_name(k): f"header.frame_id {v!r}" for k, v in frames.items()},
                         "units_from": {"gyro": "sensor_msgs/Imu (rad/s)", "accel": "sensor_msgs/Imu (m/s^2)"}})
        return MultiImuRecording(units, meta)

    for topic, ts, m in msgs:
        count += 1
        st = m.header.stamp
        t = st.sec + st.nanosec * 1e-9 if (st.sec or st.nanosec) else ts * 1e-9
        if topic not in frames:
            frames[topic] = str(m.header.frame_id)
        w, f = m.angular_velocity, m.linear_acceleration
        row = [t, w.x, w.y, w.z, f.x, f.y, f.z]
        rej = rejected.setdefault(topic, {"nonfinite": 0, "time_not_increasing": 0})
        if not all(np.isfinite(row)):
            rej["nonfinite"] += 1
            continue
        if t <= last.get(topic, -np.inf):
            rej["time_not_increasing"] += 1
            continue
        last[topic] = t
        buf.setdefault(topic, []).append(row)
        if count % chunk == 0:
            yield flush(False)
    yield flush(True)


def read(path: str | os.PathLike[str], **options: Any) -> MultiImuRecording:
    """Every ``sensor_msgs/Imu`` topic of the bag (see the module docstring)."""
    return join_chunks(iter_chunks(path, **options))
