"""Candidates and findings: a fitted term judged on held-out data, and the rules it must meet.

Shared by the baseline's order selection (``baseline.py``), the rounds of effects
(``engine.py``) and the evidence checks (``evidence.py``): the fitting problem they all refit
(`Problem`), the held-out criterion ``N ln(MSE_held_out) + k ln(N)``, the bootstrap interval of
the held-out gain over whole segments, and what is not a finding whatever its gain.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from analysis.diagnose.data import Segment
from analysis.diagnose.effects import Variant
from analysis.diagnose.fitting import FitResult
from analysis.diagnose.model import Evaluator, Model, Param, Residuals, residuals


@dataclass(frozen=True)
class Problem:
    """What every fit of a diagnosis shares: the replay, the segments fitted (a subset of the
    training segments) and judged, the response scale [m] and the residual decimation."""
    ev: Evaluator
    fit_train: list[Segment]
    test: list[Segment]
    scale_m: float
    step: int


@dataclass
class Candidate:
    effect: str
    variant: Variant
    fit: FitResult
    test: Residuals
    test_rms: float
    criterion: float
    k: int


@dataclass
class Finding:
    effect: str
    parameters: dict[str, Any]
    error_before: float
    error_after: float
    gain: float
    gain_interval: tuple[float, float]
    evidence: dict[str, Any]
    model: Model
    variant: Variant
    runner_up: Candidate | None = None
    test_residuals: Residuals | None = None  # held-out residuals of the model with it

    def parameters_text(self) -> str:
        """The parameters as the CLI and the report give them: each fitted size with its
        standard deviation where it is known (``k3_N_per_m3=2.6e+13 +- 1.7e+12``)."""
        sd = self.evidence.get("size", {}).get("sd", {})
        out = []
        for k, v in self.parameters.items():
            if not isinstance(v, float):
                out.append(f"{k}={v}")
            elif k in sd:
                out.append(f"{k}={v:.4g} +- {sd[k]:.2g}")
            else:
                out.append(f"{k}={v:.4g}")
        return ", ".join(out)

    def to_dict(self) -> dict[str, Any]:
        return {"effect": self.effect, "parameters": self.parameters,
                "error_before": self.error_before, "error_after": self.error_after,
                "gain": self.gain, "gain_interval": list(self.gain_interval),
                "evidence": self.evidence}


def bootstrap_gain(before: Residuals, after: Residuals, segs: list[Segment], seed: int,
                   n_boot: int = 2000) -> tuple[float, float]:
    """95 % percentile interval of RMS-before / RMS-after over resampled held-out segments."""
    sb = np.array([before.sse(s)[0] for s in segs])
    sa = np.array([after.sse(s)[0] for s in segs])
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(segs), size=(n_boot, len(segs)))
    ratio = np.sqrt(sb[idx].sum(axis=1) / np.maximum(sa[idx].sum(axis=1), 1e-300))
    lo, hi = np.percentile(ratio, [2.5, 97.5])
    return float(lo), float(hi)


def criterion(res: Residuals, segs: list[Segment], k: int) -> tuple[float, int]:
    """``N ln(MSE) + k ln(N)`` over ``segs`` (N residual samples, k fitted parameters), and N."""
    s, n = 0.0, 0
    for seg in segs:
        a, b = res.sse(seg)
        s += a
        n += b
    return n * math.log(max(s / n, 1e-300)) + k * math.log(n), n


def judge_candidate(pb: Problem, effect: str, var: Variant, res: FitResult,
                    n_free: int) -> Candidate:
    """The fitted term ``res`` judged on the held-out segments."""
    test_res = residuals(pb.ev, res.model, pb.fit_train, pb.test)
    k = n_free + len(var.params)
    crit, _ = criterion(test_res, pb.test, k)
    return Candidate(effect, var, res, test_res, test_res.rms(), crit, k)


def on_bound(p: Param, model: Model) -> bool:
    if p.ends_are_models:
        return False
    v = p.get(model)
    tol = 1e-3 * p.scale
    return bool((math.isfinite(p.lo) and v - p.lo <= tol)
                or (math.isfinite(p.hi) and p.hi - v <= tol))


def not_a_finding(c: Candidate, cur_train_sse: float,
                  band: tuple[float, float]) -> str | None:
    """Why candidate ``c`` cannot be a finding (None: it can).

    A term that raises the training error, a parameter held on a bound of its fit, or a mode
    outside the excited band (the data say nothing about it) explains nothing.
    """
    if c.fit.train_sse > cur_train_sse * (1 + 1e-9):
        return "raises the training error"
    bound = [p.name for p in c.variant.params if on_bound(p, c.fit.model)]
    if bound:
        return f"parameter(s) {bound} on a bound of the fit"
    if c.effect == "second_mode":
        f = c.fit.model.rig.effects.second_mode.frequency_hz
        if not band[0] <= f <= band[1]:
            return (f"mode at {f:.4g} Hz outside the excited band "
                    f"{band[0]:.4g}..{band[1]:.4g} Hz")
    return None


def total_sse(res: Residuals) -> float:
    return sum(res.sse(s)[0] for s in res.per_segment)
