"""Reproduce the reference numbers of imucal's Ferraris calibration of the real recording used in
tests/calibration/test_ferraris_real.py (constants ``IMUCAL_*`` there).

imucal is not a dependency of rimu; run this with a throwaway environment::

    python -m venv /tmp/imucal-venv && /tmp/imucal-venv/bin/pip install imucal
    /tmp/imucal-venv/bin/python benchmarks/imucal_reference.py [FOLDER]

FOLDER defaults to ../shared/data/imucal_ferraris_session relative to the repository root. imucal's model:
``raw = K R true + b`` with K diagonal (raw units per SI unit) and R with unit rows (the sensing axes); so
rimu's scale factor is ``1 / K_ii`` (times DEG_TO_RAD for the gyro, whose raw unit is deg/s) and rimu's
misalignment rows are the rows of R. Printed as JSON.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd
from imucal import FerrarisCalibration, ferraris_regions_from_section_list


def main(folder: Path) -> dict:
    data = pd.read_csv(folder / "example_ferraris_session.csv", header=0, index_col=0)
    sections = pd.read_json(folder / "example_ferraris_session_list.json").T
    regions = ferraris_regions_from_section_list(data, sections)
    cal = FerrarisCalibration().compute(regions, sampling_rate_hz=102.4, from_acc_unit="m/s^2",
                                        from_gyr_unit="deg/s")
    out = {
        "grav": 9.81,
        "expected_angle_deg": -360.0,
        "acc_K_diag": np.diag(cal.K_a).tolist(),
        "acc_R": cal.R_a.tolist(),
        "acc_b": np.asarray(cal.b_a).tolist(),
        "gyr_K_diag": np.diag(cal.K_g).tolist(),
        "gyr_R": cal.R_g.tolist(),
        "gyr_b": np.asarray(cal.b_g).tolist(),
    }
    return out


if __name__ == "__main__":
    root = Path(__file__).resolve().parents[1]
    candidates = [root / ".." / "shared" / "data" / "imucal_ferraris_session",
                  Path("/work/shared/data/imucal_ferraris_session")]
    folder = Path(sys.argv[1]) if len(sys.argv) > 1 else next((c for c in candidates if c.exists()), candidates[0])
    print(json.dumps(main(folder)))
