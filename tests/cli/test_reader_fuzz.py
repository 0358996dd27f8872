"""Property: the session readers either load a file or raise rimu's own exception, whatever the bytes.

Mutations of a valid session in both forms: the CSV text (cut, spliced, lines replaced), the JSON sidecar
(values replaced by arbitrary JSON, keys removed), the NPZ arrays (replaced by arrays of any dtype and shape,
removed) and the NPZ bytes (truncated, flipped). Derandomized, bounded examples: fast and reproducible.
"""

from __future__ import annotations

import functools
import io
import json
import os
import tempfile
import uuid
import zipfile
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from rimu.errors import RimuError
from rimu.session import Session, load_session, save_session

from .sessions import si_session

#: RIMU_FUZZ_EXAMPLES=2000 RIMU_FUZZ_RANDOM=1 for a deeper, randomized run
SETTINGS = settings(max_examples=int(os.environ.get("RIMU_FUZZ_EXAMPLES", "60")), deadline=None,
                    derandomize=not os.environ.get("RIMU_FUZZ_RANDOM"),
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


@functools.lru_cache(maxsize=1)
def _valid() -> tuple[Path, str, dict, bytes, dict]:
    d = Path(tempfile.mkdtemp(prefix="rimu-fuzz-"))
    s = si_session(n=12)
    save_session(s, d / "v.csv")
    save_session(s, d / "v.npz")
    with np.load(d / "v.npz") as z:
        arrays = {k: z[k] for k in z.files}
    return d, (d / "v.csv").read_text(), json.loads((d / "v.json").read_text()), (d / "v.npz").read_bytes(), arrays


def _loads_or_rimu_error(path: Path) -> None:
    try:
        s = load_session(path)
    except RimuError:
        return
    assert isinstance(s, Session)
    for seg in s.segments:  # what loads is usable: finite samples, increasing time
        for y in seg.raw.values():
            assert np.all(np.isfinite(y))
        assert np.all(np.diff(seg.t) > 0)


def _fresh(d: Path, suffix: str) -> Path:
    return d / f"f{uuid.uuid4().hex[:10]}{suffix}"


json_values = st.recursive(st.none() | st.booleans() | st.integers(-10**6, 10**6) | st.floats(allow_nan=True)
                           | st.text(max_size=12),
                           lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner,
                                                                                       max_size=3),
                           max_leaves=8)


@SETTINGS
@given(data=st.data())
def test_csv_text_mutations(data):
    d, text, side, _, _ = _valid()
    op = data.draw(st.sampled_from(["cut", "splice", "line", "truncate"]))
    n = len(text)
    a = data.draw(st.integers(0, n))
    if op == "cut":
        b = data.draw(st.integers(a, min(n, a + 400)))
        new = text[:a] + text[b:]
    elif op == "splice":
        new = text[:a] + data.draw(st.text(alphabet=",.-+0123456789eEnaNifP\n \t\"x", max_size=40)) + text[a:]
    elif op == "line":
        lines = text.splitlines(keepends=True)
        k = data.draw(st.integers(0, len(lines) - 1))
        lines[k] = data.draw(st.text(alphabet=",.-0123456789eEnaNifPR\"x", max_size=60)) + "\n"
        new = "".join(lines)
    else:
        new = text[:a]
    p = _fresh(d, ".csv")
    p.write_text(new)
    p.with_suffix(".json").write_text(json.dumps(dict(side, data=p.name)))
    _loads_or_rimu_error(p)


@SETTINGS
@given(data=st.data())
def test_sidecar_mutations(data):
    d, text, side, _, _ = _valid()
    side = json.loads(json.dumps(side))
    target = data.draw(st.sampled_from(["top", "segment", "geometry"]))
    if target == "top":
        obj = side
    elif target == "segment":
        obj = side["segments"][data.draw(st.integers(0, len(side["segments"]) - 1))]
    else:
        obj = side["geometries"]
        if data.draw(st.booleans()):
            side["geometries"] = {"gyro": side["geometries"]["gyro"]}
    keys = sorted(obj) if isinstance(obj, dict) else []
    if keys:
        key = data.draw(st.sampled_from(keys))
        if data.draw(st.booleans()):
            obj[key] = data.draw(json_values)
        else:
            del obj[key]
    p = _fresh(d, ".csv")
    p.write_text(text)
    side["data"] = p.name if side.get("data") is not None or target != "top" else side.get("data")
    p.with_suffix(".json").write_text(json.dumps(side))
    _loads_or_rimu_error(p)
    _loads_or_rimu_error(p.with_suffix(".json"))


@SETTINGS
@given(data=st.data())
def test_npz_array_mutations(data):
    d, _, _, _, arrays = _valid()
    arrays = dict(arrays)
    key = data.draw(st.sampled_from(sorted(arrays)))
    if data.draw(st.integers(0, 3)) == 0:
        del arrays[key]
    else:
        dtype = data.draw(st.sampled_from([np.float64, np.float32, np.int64, np.int8, np.bool_, "U3", np.complex64]))
        shape = data.draw(hnp.array_shapes(min_dims=0, max_dims=3, max_side=8)
                          | st.just(arrays[key].shape))
        arrays[key] = data.draw(hnp.arrays(dtype, shape))
    p = _fresh(d, ".npz")
    np.savez(p, **arrays)
    _loads_or_rimu_error(p)


@SETTINGS
@given(data=st.data())
def test_npz_byte_mutations(data):
    d, _, _, raw, _ = _valid()
    b = bytearray(raw)
    if data.draw(st.booleans()):
        b = b[:data.draw(st.integers(0, len(b)))]
    else:
        for _ in range(data.draw(st.integers(1, 8))):
            i = data.draw(st.integers(0, len(b) - 1))
            b[i] = data.draw(st.integers(0, 255))
    p = _fresh(d, ".npz")
    p.write_bytes(bytes(b))
    _loads_or_rimu_error(p)


def test_the_valid_files_load():
    d, *_ = _valid()
    for name in ("v.csv", "v.json", "v.npz"):
        assert len(load_session(d / name)) == 12
    assert zipfile.is_zipfile(io.BytesIO((d / "v.npz").read_bytes()))
