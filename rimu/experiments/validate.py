"""Validate a calibration on a held-out session: the runtime error and the FDI's false alarms in one call.

The session is replayed through the unit pipeline (every calibrated effect compensated,
:class:`rimu.fusion.Pipeline`) and a :class:`~rimu.fdi.manager.RedundancyManager` per instrument; the error
of the segment means against the known inputs (:mod:`rimu.fusion.validation`) says what systematic error the
calibration leaves, the alarms and isolations what it costs the FDI. On a fault-free session every isolation
is a false one.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..calibration.result import Calibration
from ..fdi.manager import ReplayResult
from ..fdi.settings import DEFAULTS as _D
from ..fdi.settings import FdiSettings
from ..fdi.unit import Runtime
from ..fusion import Pipeline
from ..fusion.validation import InstrumentErrors, segment_errors, session_block
from ..session import Session

__all__ = ["InstrumentValidation", "validate"]


@dataclass
class InstrumentValidation:
    """Runtime error and FDI outcome of one instrument over a replayed session."""

    errors: InstrumentErrors
    alarms: int
    isolations: int
    replay: ReplayResult
    #: the manager's set state after the last sample
    final_state: str = ""

    def to_dict(self) -> dict[str, Any]:
        return {**self.errors.to_dict(), "alarms": self.alarms, "isolations": self.isolations}


def validate(session: Session, calibration: Calibration, p_fa: float = _D.p_fa, confirm: int = _D.confirm,
             injections: Sequence[Any] = (), seed: int = 0, readmit_after: int | None = _D.readmit_after,
             detector: Callable[[Any], Any] | None = None,
             settings: FdiSettings | None = None) -> dict[str, InstrumentValidation]:
    """Replay ``session`` with ``calibration`` through the pipeline and the FDI (snapshot GLT at ``p_fa`` per
    sample, ``confirm`` consecutive alarms to isolate; further effects compensated with the managers in the loop,
    :class:`rimu.fdi.UnitManager`); per instrument the runtime errors, the samples that alarmed and the
    isolations. The whole session is held in memory: this is also the reference that the
    streaming ``rimu replay`` is checked against.

    ``injections`` (:class:`rimu.experiments.faults.Injection`, drawn with ``seed``) are injected into the raw data
    first; ``detector(instrument_pipeline)`` makes each manager's detector (default: the manager's own).
    ``settings`` (:class:`rimu.fdi.FdiSettings`) gives every other setting; ``p_fa``, ``confirm`` and
    ``readmit_after`` override it. The defaults are the runtime's (:data:`rimu.fdi.settings.DEFAULTS`).

    Examples
    --------
    >>> from rimu.sim import Simulator, cho_park_procedure
    >>> run = Simulator(seed=1, sample_rate=20.0).run(cho_park_procedure(duration=2.0))
    >>> v = validate(run.session, run.truth)
    >>> v["gyro"].isolations, v["gyro"].errors.segment_error_rms < 1e-3
    (0, True)
    """
    block, index = session_block(session)
    if injections:
        from .faults import inject

        block = inject(block, list(injections), calibration, seed=seed)
    insts = [k for k in calibration.instruments if k in block.raw]
    sub = Calibration({k: calibration[k] for k in insts}, calibration.raw_unit, calibration.method,
                      calibration.created, dict(calibration.metadata))
    pipe = Pipeline(sub, temperature=block.temperature is not None)
    st = FdiSettings(**{**(settings or _D).as_dict(), "p_fa": p_fa, "confirm": confirm,
                        "readmit_after": readmit_after})
    um = Runtime(pipe, st, detector_factory=detector)
    results = um.run(block)  # closed loop with the compensation of further effects (rimu.fdi.unit)
    out: dict[str, InstrumentValidation] = {}
    for k in insts:
        mgr, res = um.managers[k], results[k]
        err = segment_errors(session, k, np.asarray(res.x), index)
        n_iso = sum(1 for e in res.events if e.kind in ("isolated", "invalid_isolated"))
        out[k] = InstrumentValidation(err, int(np.count_nonzero(res.alarm)), n_iso, res, mgr.state.value)
    return out
