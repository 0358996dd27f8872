"""Fault campaigns on the shared real multi-IMU recordings: rimu's redundancy manager beside PX4's EKF2-selector
rule on the same data.

For every recording (the two-IMU Pixhawk flight; the four-Xsens-DOT quadrotor runs with all four units) the unit
is set up from the first half of its own fault-free data (:func:`rimu.calibration.multi_imu.setup_multi_imu`:
clock offsets, axis alignment, bias differences, noise from the disagreement, 0.1 s block averages). Then one
gyro fault at a time is injected into the raw full-rate data of one triad (its x sensor), at several onsets,
into every triad in turn:

* bias (a step of SIZE deg/s), drift (a ramp of SIZE deg/s per s), stuck (frozen at its last value), scale
  (output times 1.3), dropout (no data);
* rimu: the manager on the averaged gyro stream (GLT, p_fa 1e-3, 3 confirmations, invalid for 10 samples);
  detection = an isolation, or a run of 3 consecutive alarms, within 10 s of the onset; correct isolation = the
  first isolation after the onset is a sensor of the faulty triad;
* PX4 rule: :class:`rimu.fdi.Px4GyroSelector` (|gyro - median of the others| - 7 deg/s, integrated, flag at
  15 deg; 1 s timeout) on the full-rate rates rotated into the body frame with the same fitted rotations;
  detection = a flag within 10 s of the onset; correct = the first flagged IMU is the faulty one, alone.

False isolations per hour: isolations (PX4: flags) in the fault-free replays of the recordings and before the
onset in every trial, over the hours replayed. Delay: median, seconds from onset to the first correct
isolation (flag).

Also "at rest": a bias injected into the Pixhawk on the ground (first 8 s): detection only (two parallel triads
cannot isolate), smallest size detected in every trial, beside PX4's.

    python benchmarks/real_campaign.py [--data ../shared/data] [--starts 3] [--markdown]
"""

from __future__ import annotations

import os

os.environ.update(OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")  # pinned in the script

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from rimu.calibration import Calibration
from rimu.calibration.multi_imu import MultiImuSetup, setup_multi_imu
from rimu.experiments.faults import Injection, inject
from rimu.fdi import Px4GyroSelector, Runtime, fit_motion_detector, unisolated_alarm_runs
from rimu.io.pixhawk_dual import read_pixhawk_dual
from rimu.io.xsens_dot import read_xsens_dot_run
from rimu.units import DEG_TO_RAD

XSENS_RUNS = ("Horizontal/path_10", "Horizontal/path_11", "Vertical/path_1", "Vertical/path_8", "StraightLine/path_1")
#: (label, fault type, size in deg/s (drift: deg/s per s), params)
FAULTS: list[tuple[str, str, float, dict[str, Any]]] = [
    ("bias 2 deg/s", "bias", 2.0, {}),
    ("bias 5 deg/s", "bias", 5.0, {}),
    ("bias 10 deg/s", "bias", 10.0, {}),
    ("bias 20 deg/s", "bias", 20.0, {}),
    ("drift 1 deg/s/s", "ramp", 1.0, {"ramp_time": 1.0}),
    ("stuck", "stuck", 0.0, {}),
    ("scale x1.3", "scale", 0.0, {"factor": 1.3}),
    ("dropout", "dropout", 0.0, {}),
]
GROUND_BIASES = (0.5, 1.0, 2.0, 5.0, 7.5, 10.0, 15.0)
#: a detection (isolation, flag) counts when it comes within this many seconds of the onset
WINDOW_S = 10.0
P_FA, CONFIRM = 1e-3, 3


def default_data() -> Path:
    """``../shared/data`` beside the repository, else ``/work/shared/data``."""
    for p in (Path(__file__).resolve().parents[1] / ".." / "shared" / "data", Path("/work/shared/data")):
        if p.exists():
            return p.resolve()
    return Path("../shared/data")


def load_recordings(data: Path) -> dict[str, Any]:
    """The shared multi-IMU recordings present under ``data`` (absent ones are skipped)."""
    recs: dict[str, Any] = {}
    px = data / "pixhawk1_dual_imu_flight"
    if (px / "01_07_59_imu01.csv.xz").exists():
        recs["pixhawk"] = read_pixhawk_dual(px)
    for run in XSENS_RUNS:
        d = data / "quadrotor_4x_xsens_dot" / run
        if d.exists():
            recs["xsens " + run] = read_xsens_dot_run(d)
    return recs


def setup(rec: Any) -> MultiImuSetup:
    """The recipe of docs/real-units.md: fit on the first half, 0.1 s averages."""
    t_end = max(u.t[-1] for u in rec.units)
    return setup_multi_imu(rec, average_s=0.1, fit_window_s=(-np.inf, 0.5 * t_end))


def body_rates(su: MultiImuSetup, block: Any) -> tuple[np.ndarray, np.ndarray]:
    """Full-rate gyro of every triad, bias-compensated and rotated into MB: (N, k, 3), valid (N, k)."""
    cal = su.calibration["gyro"]
    k = cal.geometry.n // 3
    Y = np.where(block.valid["gyro"], block.raw["gyro"], np.nan) - cal.bias
    W = np.stack([Y[:, 3 * j:3 * j + 3] @ cal.geometry.subunits[j].mat_sb_mb for j in range(k)], axis=1)
    return W, block.valid["gyro"].reshape(len(block), k, 3).all(axis=2)


_RUNTIMES: dict[int, Runtime] = {}
#: the detector of rimu's manager: "glt" (the snapshot GLT under the noise fitted at setup) or "motion" (the
#: motion-aware GLT, its motion terms fitted on the same fault-free first half: benchmarks/real_campaign_motion.py)
DETECTOR = "glt"
MOTION_MARGIN = 10.0


def runtime(su: MultiImuSetup) -> Runtime:
    """One runtime (rimu.fdi.Runtime, the one owner of a unit's state: what rimu replay and monitor step) of the
    unit's gyros per setup, reset before every replay."""
    key = id(su)
    if key not in _RUNTIMES:
        cal = su.calibration["gyro"]
        det = None
        if DETECTOR == "motion":
            b = su.block
            first = (b.t >= su.fit_window_s[0]) & (b.t <= su.fit_window_s[1])
            det = fit_motion_detector(cal, b.raw["gyro"][first], b.valid["gyro"][first],
                                      1.0 / float(np.median(np.diff(b.t))), margin=MOTION_MARGIN, p_fa=P_FA)
        gyro_only = Calibration({"gyro": cal}, su.calibration.raw_unit)
        _RUNTIMES[key] = Runtime(gyro_only, p_fa=P_FA, confirm=CONFIRM,
                                 detector_factory=None if det is None else (lambda ip, det=det: det))
    rt = _RUNTIMES[key]
    rt.reset()
    return rt


def run_rimu(su: MultiImuSetup, block: Any) -> tuple[list[tuple[float, str, str]], float]:
    """Events (t, kind, sensor) of a freshly reset manager over the averaged block; seconds per sample.

    Kinds: ``isolated``, ``invalid_isolated``, and ``detected`` for every run of ``confirm`` consecutive alarms
    that led to no isolation (a unit that cannot isolate, such as two parallel triads, reports the fault as
    detected; the manager logs ``detected_not_isolable`` only once until the next isolation)."""
    rt = runtime(su)
    t0 = time.perf_counter()
    res = rt.run(block)["gyro"]
    dt = (time.perf_counter() - t0) / len(block)
    ev = [(e.t, e.kind, e.sensor or "") for e in res.events if e.kind in ("isolated", "invalid_isolated")]
    ev += [(tt, "detected", "") for tt in unisolated_alarm_runs(res, CONFIRM)]
    return sorted(ev), dt


def run_px4(su: MultiImuSetup, full: Any) -> tuple[Any, float]:
    W, V = body_rates(su, full)
    t0 = time.perf_counter()
    r = Px4GyroSelector().run(full.t, W, V)
    return r, (time.perf_counter() - t0) / len(full)


def trial(su: MultiImuSetup, triad: int, start: float, fault: tuple[str, str, float, dict[str, Any]],
          duration: float | None = None) -> dict[str, Any]:
    label, kind, size, params = fault
    names = su.calibration["gyro"].geometry.names
    sensor = names[3 * triad]
    inj = Injection(kind, "gyro", sensor, start, size * DEG_TO_RAD, False, duration, dict(params))
    full = inject(su.full_block, [inj], su.calibration)
    ev, _ = run_rimu(su, su.average(full))
    px, _ = run_px4(su, full)
    triad_name = su.calibration["gyro"].geometry.subunits[triad].name
    out: dict[str, Any] = {"fault": label, "triad": triad, "start": start}
    before = [e for e in ev if e[0] < start and e[1] != "detected"]
    after = [e for e in ev if start <= e[0] <= start + WINDOW_S]
    out["rimu_false"] = len(before)
    out["rimu_false_detections"] = sum(1 for e in ev if e[0] < start and e[1] == "detected")
    out["rimu_detected"] = bool(after)
    iso = [e for e in after if e[1] in ("isolated", "invalid_isolated")]
    out["rimu_correct"] = bool(iso) and iso[0][2].startswith(triad_name + "_")
    out["rimu_delay"] = iso[0][0] - start if out["rimu_correct"] else (after[0][0] - start if after else None)
    tf = px.t_flag
    out["px4_false"] = int(np.sum(tf < start))
    who, t_first, amb = Px4GyroSelector_first_after(np.where(tf <= start + WINDOW_S, tf, np.nan), start)
    out["px4_detected"] = who >= 0
    out["px4_correct"] = who == triad and not amb
    out["px4_delay"] = (t_first - start) if who >= 0 else None
    out["hours_before"] = (start - su.full_block.t[0]) / 3600.0
    return out


def Px4GyroSelector_first_after(t_flag: np.ndarray, start: float) -> tuple[int, float, bool]:
    """First IMU flagged at or after ``start`` (ambiguous when several at the same time)."""
    tf = np.where(t_flag >= start, t_flag, np.nan)
    if not np.any(np.isfinite(tf)):
        return -1, float("nan"), False
    m = np.nanmin(tf)
    who = np.flatnonzero(tf == m)
    return int(who[0]), float(m), len(who) > 1


def summarise(rows: list[dict[str, Any]], hours_clean: float, false_clean: dict[str, int]) -> list[dict[str, Any]]:
    out = []
    hours = hours_clean + sum(r["hours_before"] for r in rows)
    labels = list(dict.fromkeys(r["fault"] for r in rows))
    for lab in labels:
        rs = [r for r in rows if r["fault"] == lab]
        row: dict[str, Any] = {"fault": lab, "trials": len(rs)}
        for who in ("rimu", "px4"):
            row[f"{who}_detected"] = float(np.mean([r[f"{who}_detected"] for r in rs]))
            row[f"{who}_correct"] = float(np.mean([r[f"{who}_correct"] for r in rs]))
            d = [r[f"{who}_delay"] for r in rs if r[f"{who}_correct"] and r[f"{who}_delay"] is not None]
            row[f"{who}_delay_s"] = float(np.median(d)) if d else None
        out.append(row)
    fph = {who: (false_clean[who] + sum(r[f"{who}_false"] for r in rows)) / hours if hours > 0 else float("nan")
           for who in ("rimu", "px4")}
    fdet = (false_clean["rimu_detections"] + sum(r["rimu_false_detections"] for r in rows)) / hours
    for row in out:
        row["rimu_false_per_h"] = fph["rimu"]
        row["px4_false_per_h"] = fph["px4"]
        row["rimu_false_detections_per_h"] = fdet
        row["hours"] = hours
    return out


def fmt_table(title: str, summary: list[dict[str, Any]]) -> str:
    def pct(x: float) -> str:
        return f"{100 * x:.0f} %"

    def sec(x: float | None) -> str:
        return "-" if x is None else f"{x:.2f}"

    lines = [f"#### {title}", "",
             ("| fault (one triad) | trials | rimu detected | rimu correct isolation | rimu delay s | "
              "PX4 rule detected | PX4 rule correct | PX4 rule delay s |"),
             "|---|---|---|---|---|---|---|---|"]
    for r in summary:
        lines.append(f"| {r['fault']} | {r['trials']} | {pct(r['rimu_detected'])} | {pct(r['rimu_correct'])} | "
                     f"{sec(r['rimu_delay_s'])} | {pct(r['px4_detected'])} | {pct(r['px4_correct'])} | "
                     f"{sec(r['px4_delay_s'])} |")
    if summary:
        lines.append("")
        r0 = summary[0]
        lines.append(f"False isolations (PX4 rule: flags) per hour, in the fault-free replays and before every "
                     f"onset ({r0['hours']:.2f} h): rimu {r0['rimu_false_per_h']:.1f}, PX4 rule "
                     f"{r0['px4_false_per_h']:.1f}; rimu's confirmed alarms that isolated nothing: "
                     f"{r0['rimu_false_detections_per_h']:.0f} per hour (so a 'detected' within the "
                     f"{WINDOW_S:g} s window comes by chance with probability "
                     f"{1 - np.exp(-r0['rimu_false_detections_per_h'] * WINDOW_S / 3600):.0%}).")
    return "\n".join(lines)


def ground_bias(su: MultiImuSetup, starts: int) -> dict[str, Any]:
    """Pixhawk on the ground (first 8 s): smallest bias detected in every trial, rimu and PX4 rule."""
    res: dict[str, Any] = {"sizes_deg_s": list(GROUND_BIASES), "rimu": [], "px4": []}
    onsets = np.linspace(1.0, 2.0, starts)
    for size in GROUND_BIASES:
        det = {"rimu": [], "px4": []}
        for triad in (0, 1):
            for s in onsets:
                r = trial(su, triad, float(s), ("ground", "bias", size, {}), duration=6.0)
                det["rimu"].append(r["rimu_detected"] and (r["rimu_delay"] or 0) <= 6.0)
                det["px4"].append(r["px4_detected"] and (r["px4_delay"] or 0) <= 6.0)
        for who in ("rimu", "px4"):
            res[who].append(float(np.mean(det[who])))
    for who in ("rimu", "px4"):
        ok = [s for s, f in zip(GROUND_BIASES, res[who]) if f >= 1.0]
        res[f"{who}_min_deg_s"] = ok[0] if ok else None
    return res


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=None, help="the shared data folder (default ../shared/data, then "
                    "/work/shared/data)")
    ap.add_argument("--starts", type=int, default=3, help="onsets per triad and fault")
    args = ap.parse_args()
    data = Path(args.data) if args.data else default_data()
    recs = load_recordings(data)
    if not recs:
        print(f"no shared recordings under {data}; nothing to do")
        return
    t_all = time.perf_counter()
    groups: dict[str, list[dict[str, Any]]] = {"pixhawk": [], "xsens": []}
    clean_hours = {"pixhawk": 0.0, "xsens": 0.0}
    clean_false = {g: {"rimu": 0, "px4": 0, "rimu_detections": 0} for g in ("pixhawk", "xsens")}
    cost = {"rimu": [], "px4": []}
    ground = None
    for name, rec in recs.items():
        grp = "pixhawk" if name == "pixhawk" else "xsens"
        su = setup(rec)
        ev, c_r = run_rimu(su, su.block)
        px, c_p = run_px4(su, su.full_block)
        cost["rimu"].append(c_r / su.n_average)  # per full-rate sample of data (it runs once per n_average)
        cost["px4"].append(c_p)
        clean_false[grp]["rimu"] += sum(1 for e in ev if e[1] != "detected")
        clean_false[grp]["rimu_detections"] += sum(1 for e in ev if e[1] == "detected")
        clean_false[grp]["px4"] += int(np.isfinite(px.t_flag).sum())
        T0, T1 = su.full_block.t[0], su.full_block.t[-1]
        clean_hours[grp] += (T1 - T0) / 3600.0
        k = su.calibration["gyro"].geometry.n // 3
        onsets = T0 + (T1 - T0) * np.linspace(0.3, 0.7, args.starts)
        for fault in FAULTS:
            for triad in range(k):
                for s in onsets:
                    groups[grp].append(trial(su, triad, float(s), fault))
        if grp == "pixhawk":
            ground = ground_bias(su, args.starts)
    elapsed = time.perf_counter() - t_all
    out_md: list[str] = []
    summaries = {}
    for grp, title in (("xsens", "Four Xsens DOT on a quadrotor (5 runs, gyro faults in flight)"),
                       ("pixhawk", "Pixhawk 1, two IMUs (gyro faults in flight)")):
        if groups[grp]:
            summaries[grp] = summarise(groups[grp], clean_hours[grp], clean_false[grp])
            out_md.append(fmt_table(title, summaries[grp]))
    if ground is not None:
        g = ["#### Pixhawk on the ground, first 8 s: a bias on one triad (two parallel triads: detection only)", "",
             "| bias deg/s | " + " | ".join(f"{s:g}" for s in ground["sizes_deg_s"]) + " |",
             "|---|" + "---|" * len(ground["sizes_deg_s"])]
        for who, lab in (("rimu", "rimu detected within 6 s"), ("px4", "PX4 rule flagged within 6 s")):
            g.append(f"| {lab} | " + " | ".join(f"{100 * f:.0f} %" for f in ground[who]) + " |")
        g += ["", (f"Smallest bias detected in every trial: rimu {ground['rimu_min_deg_s']} deg/s, PX4 rule "
                  f"{ground['px4_min_deg_s']} deg/s.")]
        out_md.append("\n".join(g))
    out_md.append(f"Cost per full-rate sample (median over recordings): rimu manager on 0.1 s averages "
                  f"{1e6 * np.median(cost['rimu']):.1f} us, PX4 rule {1e6 * np.median(cost['px4']):.1f} us; "
                  f"campaign {elapsed:.0f} s.")
    print("\n\n".join(out_md))
    print(json.dumps({"summaries": summaries, "ground": ground, "clean_hours": clean_hours,
                      "clean_false": clean_false, "cost_us_per_sample": {k: 1e6 * float(np.median(v))
                                                                          for k, v in cost.items()},
                      "elapsed_s": elapsed}, default=float))


if __name__ == "__main__":
    main()
