"""The seal friction a lubricated analysis removes, from what the runs say about their seal.

Order of evidence: the runs' own conditions (no seal: F_mu = 0; a stated F_mu), a dry run given
with them (energy balance, eq. 2-4), a fit of F_mu to the lubricated dwells themselves when the
runs say the seal is there but its friction unknown, then the rig configuration (simulated runs)
or the report's Table 4 (26 N).

The fit uses eq. 9 and eq. 11: C_t = (C_sfd + C_rv) + (4 F_mu / pi) / (w |Z|), a straight line in
1 / (w |Z|) across the dwells of all frequencies and amplitudes; it assumes C_sfd does not depend
on the amplitude (true at the centre, within a few % for |Z| < 0.3 c by eq. 16).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from analysis.dwells import Dwell


@dataclass
class SealSetting:
    """The seal the runs declare: ``state`` is "none", "given", "unknown" or "" (not stated)."""

    state: str
    f_mu_n: float | None
    source: str


def declared_seal(test_specs: list[dict[str, Any] | None], labels: list[str]) -> SealSetting:
    """The seal stated in the runs' import conditions; runs disagreeing is reported as such."""
    stated: dict[str, list[str]] = {}
    for spec, label in zip(test_specs, labels, strict=True):
        cond = (spec or {}).get("conditions") or {}
        seal = str(cond.get("seal") or "")
        if seal:
            src = (cond.get("sources") or {}).get("seal", "")
            stated.setdefault(seal, []).append(f"{label}: {src}" if src else label)
    if not stated:
        return SealSetting("", None, "")
    if len(stated) > 1:
        desc = "; ".join(f"{k} ({', '.join(v)})" for k, v in stated.items())
        raise ValueError(f"the lubricated runs state different seals: {desc}; identify them "
                         "separately")
    seal, who = next(iter(stated.items()))
    where = ", ".join(who)
    if seal == "none":
        return SealSetting("none", 0.0, f"no end seal (run conditions, {where}): C_seal = 0")
    if seal == "unknown":
        return SealSetting("unknown", None, f"seal present, friction unknown ({where})")
    return SealSetting("given", float(seal), f"F_mu = {float(seal):g} N stated in the run "
                       f"conditions ({where})")


def fit_seal_friction(dwells: list[Dwell]) -> tuple[float, float, float, int]:
    """(F_mu [N], its 95 % uncertainty [N], C_sfd + C_rv [N.s/m], points) by eq. 9 regression.

    Raises
    ------
    ValueError
        When fewer than 3 unidirectional dwells with distinct w |Z| are available.
    """
    xs, ys = [], []
    for dw in dwells:
        axis = {"x": "x", "y": "y"}.get(dw.motion)
        if axis is None or axis not in dw.harmonics or "f" + axis not in dw.harmonics:
            continue
        z, f = dw.z1(axis), dw.z1("f" + axis)
        if abs(z) == 0:
            continue
        w = dw.omega
        xs.append(1.0 / (w * abs(z)))
        ys.append((f / (1j * w * z)).real)
    x, y = np.asarray(xs), np.asarray(ys)
    if x.size < 3 or np.ptp(x) <= 1e-9 * np.max(x):
        raise ValueError(f"{x.size} unidirectional dwell(s) with distinct w|Z|: at least 3 "
                         "needed to fit F_mu")
    design = np.column_stack([np.ones_like(x), x])
    coef, *_ = np.linalg.lstsq(design, y, rcond=None)
    resid = y - design @ coef
    dof = max(x.size - 2, 1)
    cov = np.linalg.inv(design.T @ design) * float(resid @ resid) / dof
    slope, u_slope = float(coef[1]), 2.0 * float(np.sqrt(cov[1, 1]))
    return slope * np.pi / 4, u_slope * np.pi / 4, float(coef[0]), int(x.size)
