"""Log-log Allan deviation plots with the fitted slopes (matplotlib, headless; optional extra ``plots``)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from ..plotting import pyplot, save_figure
from ..units import MS2_TO_UG, RS_TO_DH
from .model import FIELD_UNITS, FLICKER_AVAR, TERMS, InstrumentNoise

__all__ = ["plot_instrument", "plot_parity"]

#: Allan deviation slope of each term on a log-log plot
SLOPES = {"quantization": -1.0, "white": -0.5, "bias_instability": 0.0, "rate_random_walk": 0.5}
#: deviation units of the curve itself (rate) per instrument, and the factor from SI
DEV_UNITS = {"gyro": ("deg/h", RS_TO_DH), "accel": ("micro-g", MS2_TO_UG)}


def _asymptote(term: str, value: float, tau: np.ndarray) -> np.ndarray:
    """The term's own Allan deviation, SI (IEEE Std 952, Annex C)."""
    if term == "quantization":
        return math.sqrt(3.0) * value / tau
    if term == "white":
        return value / np.sqrt(tau)
    if term == "bias_instability":
        return np.full_like(tau, math.sqrt(FLICKER_AVAR) * value)
    return value * np.sqrt(tau / 3.0)


def plot_instrument(model: InstrumentNoise, path: str | Path) -> Path:
    """Every sensor's Allan deviation with its one-sigma interval and fitted model, and the mean fitted slopes
    (-1, -1/2, 0, +1/2) labelled with their values in the field's units. Returns the PNG path."""
    plt = pyplot()
    if model.allan is None:
        raise ValueError("this noise model holds no measured Allan deviation to plot (it was given by hand)")
    unit, f = DEV_UNITS[model.instrument]
    tau = np.asarray(model.allan["tau"])
    adev, lo, hi = (np.asarray(model.allan[k]) for k in ("adev", "lo", "hi"))
    fig, ax = plt.subplots(figsize=(8, 5.5))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    fit = np.sqrt(model.avar(tau))
    for i, name in enumerate(model.names):
        c = colours[i % len(colours)]
        ax.errorbar(tau, adev[i] * f, yerr=[(adev[i] - lo[i]) * f, (hi[i] - adev[i]) * f], fmt=".", ms=3, color=c,
                    elinewidth=0.6, label=name)
        ax.plot(tau, fit[i] * f, "-", color=c, lw=0.8, alpha=0.8)
    field = FIELD_UNITS[model.instrument]
    span = np.geomspace(tau[0], tau[-1], 50)
    for t in TERMS:
        v = float(np.mean(model.terms[t]))
        if v <= 0:
            continue
        s = float(np.mean(model.sigma[t]))
        label = f"slope {SLOPES[t]:+g}: {t.replace('_', ' ')} {v * field[t][1]:.3g} +/- {s * field[t][1]:.2g} {field[t][0]}"
        ls = {"quantization": ":", "white": "--", "bias_instability": "-.", "rate_random_walk": (0, (5, 1, 1, 1, 1, 1))}
        ax.plot(span, _asymptote(t, v, span) * f, linestyle=ls[t], color="k", lw=1.0, alpha=0.7, label=label)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("averaging time tau [s]")
    ax.set_ylabel(f"Allan deviation [{unit}]")
    ax.set_ylim(max(float(np.min(lo[lo > 0])) * f * 0.3, 1e-300), float(np.max(hi)) * f * 2.0)
    ax.set_title(f"{model.instrument}: overlapping Allan deviation, one-sigma intervals, fitted model (IEEE Std 952)",
                 fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, ncol=1, loc="lower left")
    fig.tight_layout()
    return save_figure(fig, path)


def plot_parity(parity: dict[str, Any], path: str | Path) -> Path:
    """The normalised parity components' Allan deviation ``adev sqrt(m)`` (1 for white noise), their
    intervals, and the prediction from independent sensors. ``parity`` is a ParityWhiteness ``to_dict()``."""
    plt = pyplot()
    tau = np.asarray(parity["tau"])
    nd, lo, hi = (np.asarray(parity[k]) for k in ("normalised_adev", "normalised_lo", "normalised_hi"))
    pred = parity.get("predicted_independent")
    fig, ax = plt.subplots(figsize=(8, 5))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for k in range(nd.shape[0]):
        c = colours[k % len(colours)]
        ax.errorbar(tau, nd[k], yerr=[nd[k] - lo[k], hi[k] - nd[k]], fmt=".", ms=3, color=c, elinewidth=0.6,
                    label=f"p{k}")
        if pred is not None:
            ax.plot(tau, np.asarray(pred)[k], "-", color=c, lw=0.8, alpha=0.8)
    ax.axhline(1.0, color="k", ls="--", lw=1.0, label="white (unit variance)")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("averaging time tau [s]")
    ax.set_ylabel("adev x sqrt(m)  [1 = white]")
    ax.set_title(f"{parity['instrument']} parity: {'white' if parity['white'] else 'not white'}; "
                 f"{'independent' if parity.get('independent') else 'not independent'} (lines: independent sensors)",
                 fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    return save_figure(fig, path)
