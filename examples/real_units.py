"""Real units: from a real multi-IMU log to a fused, monitored output (docs/real-units.md).

Reads the four-Xsens-DOT quadrotor run (or the two-IMU Pixhawk flight), sets the unit up from the first half of
its own data (clock offsets, axis alignment, bias differences, noise from the disagreement, 0.1 s averages),
fuses every triad into one estimate in the body frame with its covariance, monitors it with the redundancy
manager, and replays it twice: as recorded, and with a 10 deg/s gyro bias injected into one triad halfway.
Plots the fused rate, the normalised parity with its threshold and the validity flag (health state, active
sensors) over the flight.

    python examples/real_units.py [quadrotor|pixhawk] [data_folder] [out_folder] [--no-plot]
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np

from rimu.calibration import Calibration
from rimu.calibration.multi_imu import MultiImuSetup, setup_multi_imu
from rimu.experiments.faults import Injection, inject
from rimu.fdi import Runtime
from rimu.fdi.manager import STATE_CODES
from rimu.io.pixhawk_dual import read_pixhawk_dual
from rimu.io.xsens_dot import read_xsens_dot_run
from rimu.units import DEG_TO_RAD, RAD_TO_DEG


def default_data() -> Path:
    for p in (Path(__file__).resolve().parents[1] / ".." / "shared" / "data", Path("/work/shared/data")):
        if p.exists():
            return p.resolve()
    return Path("../shared/data")


def load(which: str, data: Path) -> Any:
    if which == "pixhawk":
        return read_pixhawk_dual(data / "pixhawk1_dual_imu_flight")
    return read_xsens_dot_run(data / "quadrotor_4x_xsens_dot" / "Horizontal" / "path_10")


def replay(su: MultiImuSetup, block: Any, instrument: str = "gyro") -> dict[str, Any]:
    """Fuse and monitor one instrument over a block: estimate, covariance, parity, statistic, state, events."""
    # the one runtime owner of the unit's state (rimu.fdi.Runtime: what rimu replay and rimu monitor step)
    rt = Runtime(Calibration({instrument: su.calibration[instrument]}, su.calibration.raw_unit), p_fa=1e-3, confirm=3)
    res = rt.run(block)[instrument]
    mgr = rt.managers[instrument]
    return {"t": block.t, "x": res.x, "statistic": res.statistic, "threshold": res.threshold,
            "state": res.state, "n_active": res.n_active, "events": res.events, "alarm": res.alarm,
            "final_state": mgr.state.value, "isolated": list(mgr.health.isolated)}


def plot(path: Path, su: MultiImuSetup, runs: dict[str, dict[str, Any]], title: str) -> Path | None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib is not installed (pip install 'rimu[plots]'): no plot")
        return None
    fig, axes = plt.subplots(3, len(runs), figsize=(6.5 * len(runs), 8.5), sharex=True, squeeze=False)
    names = {v: k.value for k, v in STATE_CODES.items()}
    for c, (lab, r) in enumerate(runs.items()):
        ax = axes[0, c]
        for a, col in zip("xyz", ("C0", "C1", "C2")):
            i = "xyz".index(a)
            ax.plot(r["t"], r["x"][:, i] * RAD_TO_DEG, col, lw=0.8, label=f"fused {a}")
        ax.set_ylabel("rate in MB, deg/s")
        ax.set_title(f"{title}: {lab}")
        ax.legend(loc="upper right", fontsize=7)
        ax = axes[1, c]
        ax.semilogy(r["t"], np.maximum(r["statistic"], 1e-3), "k", lw=0.6, label="parity statistic |p|^2")
        thr = np.where(np.isfinite(r["threshold"]), r["threshold"], np.nan)
        ax.semilogy(r["t"], thr, "r--", lw=0.8, label="threshold (p_fa 1e-3)")
        for e in r["events"]:
            if e.kind in ("isolated", "invalid_isolated"):
                ax.axvline(e.t, color="m", lw=0.8)
                ax.text(e.t, ax.get_ylim()[1] if ax.get_ylim()[1] > 0 else 1, f" {e.sensor}", color="m", fontsize=7,
                        va="top")
        ax.set_ylabel("normalised parity")
        ax.legend(loc="upper right", fontsize=7)
        ax = axes[2, c]
        ax.step(r["t"], r["n_active"], "b", where="post", lw=0.9, label="active sensors")
        ax.set_ylabel("active sensors", color="b")
        ax2 = ax.twinx()
        ax2.step(r["t"], r["state"], "g", where="post", lw=0.9)
        ax2.set_ylim(-0.3, max(names) + 0.3)
        ax2.set_yticks(sorted(names))
        ax2.set_yticklabels([names[k] for k in sorted(names)], fontsize=7)
        ax2.set_ylabel("validity (health state)", color="g")
        ax.set_xlabel("t, s")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> dict[str, Any]:
    argv = sys.argv[1:] if argv is None else argv
    want_plot = "--no-plot" not in argv
    argv = [a for a in argv if a != "--no-plot"]
    which = argv[0] if argv else "quadrotor"
    data = Path(argv[1]) if len(argv) > 1 else default_data()
    out = Path(argv[2]) if len(argv) > 2 else Path("rimu-example")
    out.mkdir(parents=True, exist_ok=True)
    rec = load(which, data)
    t_end = max(u.t[-1] for u in rec.units)
    su = setup_multi_imu(rec, average_s=0.1, fit_window_s=(-np.inf, 0.5 * t_end))
    print(su.report())
    # as recorded
    runs = {"as recorded": replay(su, su.block)}
    # with a 10 deg/s bias on the x gyro of the last triad, halfway through
    k = len(rec.names)
    sensor = f"{rec.names[-1]}_x"
    t_fault = float(su.full_block.t[0] + 0.5 * (su.full_block.t[-1] - su.full_block.t[0]))
    faulty = su.average(inject(su.full_block, [Injection("bias", "gyro", sensor, t_fault, 10 * DEG_TO_RAD)],
                               su.calibration))
    runs[f"10 deg/s bias on {sensor} at {t_fault:.1f} s"] = replay(su, faulty)
    for lab, r in runs.items():
        ev = [(e.kind, e.sensor, round(e.t, 2)) for e in r["events"]
              if e.kind not in ("transient", "invalid_transient")]
        print(f"{lab}: final state {r['final_state']}, isolated {r['isolated']}, alarms in "
              f"{r['alarm'].mean():.1%} of samples, events {ev[:6]}")
    acc = replay(su, su.block, "accel")
    print(f"accelerometers as recorded: final state {acc['final_state']}, isolated {acc['isolated']}")
    png = (plot(out / f"real_units_{which}.png", su, runs, "Xsens DOT x4" if which != "pixhawk" else "Pixhawk x2")
           if want_plot else None)
    print(f"{k} triads, {len(su.block)} epochs at {1 / np.median(np.diff(su.block.t)):.1f} Hz -> "
          f"{png if png else 'no plot'}")
    return {"setup": su, "runs": runs, "accel": acc, "png": png}


if __name__ == "__main__":
    main()
