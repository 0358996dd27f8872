#!/usr/bin/env python3
"""The real-recording fault campaign of ``real_campaign.py`` with rimu's manager on the motion-aware GLT
(:func:`rimu.fdi.fit_motion_detector`: scale, misalignment, time offset and vibration terms fitted, with a margin
of 10, on the same fault-free first half of each recording that the setup uses), beside the same PX4 rule.
Compare with the ``real_campaign`` section (plain GLT): the confirmed alarms that isolate nothing in fault-free
flight fall, the detections and isolations of the faults are the ones to watch.

    python benchmarks/real_campaign_motion.py [--data ../shared/data] [--starts 3]
"""

from __future__ import annotations

import os

os.environ.update(OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")  # pinned in the script

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import real_campaign

if __name__ == "__main__":
    real_campaign.DETECTOR = "motion"
    real_campaign.main()
