"""``import rimu`` and ``import rimu.session`` import no calibration estimator, scipy, matplotlib or numba; the
top-level names and subpackages still resolve on first use (PEP 562)."""

from __future__ import annotations

import subprocess
import sys


def _modules_after(code: str) -> set[str]:
    out = subprocess.run([sys.executable, "-c", f"import sys\n{code}\nprint(' '.join(sys.modules))"],
                         capture_output=True, text=True, check=True).stdout
    return set(out.split())


def test_session_import_stays_light():
    for code in ("import rimu", "import rimu.session", "from rimu.session import load_session, iter_blocks"):
        mods = _modules_after(code)
        heavy = {m for m in mods if m.split(".")[0] in ("scipy", "matplotlib", "numba")}
        assert not heavy, (code, sorted(heavy)[:5])
        assert "rimu.calibration" not in mods and "rimu.fdi" not in mods, code


def test_top_level_names_resolve_on_first_use():
    import rimu
    from rimu.calibration import Calibration
    from rimu.epoch import INSTRUMENTS
    from rimu.session import Session

    assert rimu.Calibration is Calibration and rimu.Session is Session and rimu.INSTRUMENTS is INSTRUMENTS
    assert rimu.fdi.RedundancyManager.__name__ == "RedundancyManager"  # a subpackage, as after an eager import
    assert set(rimu.__all__) <= set(dir(rimu))
    try:
        rimu.no_such_name  # noqa: B018
    except AttributeError as exc:
        assert "no_such_name" in str(exc)
    else:
        raise AssertionError("an unknown name must raise AttributeError")
