"""The hidden-effect cases of the harmonic-balance generator, their detectability and the
judgement of a diagnosis.

Detectability is the generator's own, from its noise model (never from what diagnose finds):
per dwell, the measured fundamentals (after the sensors) give the x dynamic stiffness
H = F / X, the accelerometer-to-probe ratio R = A / X and the y probe's response Y (phase
referred to the x probe). A linear rig (one mode per axis, uncoupled, rigid frame, exact
sensors) has Re H = K - w^2 M, Im H = w C, R = -w^2 and Y = 0: K, M, C are fitted to the dwells
(weighted least squares) and the rest is the effect's signature, in standard deviations of
each dwell's estimate (noise sigma with quantisation, sqrt(2 / N) for a fundamental from N
samples, propagated to the ratio). ``Signature.per_dwell_max`` is the largest dwell's,
``total`` the root sum of squares over the run.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from tests.independent_hb.generate import DwellRecord, plan, record, sensors_for, solve_plan
from tests.independent_hb.rig import (
    STIFFNESS_X_N_PER_M,
    VISCOSITY_PER_C,
    BoucWen,
    Frame,
    Hidden,
    Rig,
)
from tests.independent_hb.sensors import SensorModel

#: the cubic spring: the equivalent stiffness (3/4 k3 A^2) 4 % above K_x at 38 um
K3_N_PER_M3 = 0.04 * STIFFNESS_X_N_PER_M / (0.75 * 38e-6**2)
#: oil warming that takes the film's damping down 25 % (eq. 1)
WARMING_C = -math.log(0.75) / VISCOSITY_PER_C
#: the per-dwell signature the threshold-sized friction is given, in noise standard deviations
THRESHOLD_SIGMAS = 8.0


@dataclass(frozen=True)
class Expected:
    """A cause diagnose should name: its library id, main parameter and true value, the
    channel (sensor effects) and the channels the data cannot tell it from (``alike``), and the
    allowance for the generator's own law against the library's (added to the noise's
    tolerance).

    ``alike``: the probe's gain is not told from the accelerometer's on these records. A
    fault on the probe moves both F / X and A / X where one on the force cell moves F / X
    alone, but diagnose's baseline is fitted (no rig description): a probe gain g gives
    F / X = S / g and A / X = -w^2 / g, the same fundamentals as an accelerometer gain 1 / g on
    a structure S / g (mass, damping and stiffness over g), to the last digit on a linear rig
    (``test_judgement``: fitted to each other's noise-free fundamentals, 0 sd apart). Only an
    absolute reference (the structure's known mass or stiffness) tells them apart. The force
    cell's gain moves F / X alone: it is told from the probe's."""

    effect: str
    parameter: str
    value: float
    channel: str | None = None
    model_allowance: float = 0.01
    alike: tuple[str, ...] = ()


@dataclass(frozen=True)
class Case:
    name: str
    hidden: Hidden
    expected: tuple[Expected, ...] = ()
    outside_library: bool = False  # right answer: honest "unexplained", no confident cause
    notes: dict[str, Any] = field(default_factory=dict)


def cases(seed: int = 1) -> dict[str, Case]:
    """Every case; the threshold friction sized to ``THRESHOLD_SIGMAS`` on ``seed``'s plan."""
    return {c.name: c for c in _cases(seed)}


@functools.cache
def _cases(seed: int) -> tuple[Case, ...]:
    """`cases`, built once per process and seed (each test and the collection ask for them)."""
    small = threshold_friction(seed)
    bw = BoucWen(force_n=20.0, stiffness_n_per_m=2e6)
    out = [
        Case("clean", Hidden()),
        Case("friction_threshold", Hidden(seal_friction_n=small),
             (Expected("coulomb_friction", "friction_force_N", small),)),
        Case("friction_large", Hidden(seal_friction_n=15.0),
             (Expected("coulomb_friction", "friction_force_N", 15.0),)),
        Case("cubic_spring", Hidden(cubic_k3_n_per_m3=K3_N_PER_M3),
             (Expected("cubic_stiffness", "k3_N_per_m3", K3_N_PER_M3),)),
        Case("stiffness_drift", Hidden(stiffness_drift=0.10), outside_library=True),
        Case("probe_gain", Hidden(probe_gain_x=1.04),
             (Expected("sensor_gain", "gain_ratio", 1.04, channel="x", alike=("ax",)),)),
        Case("oil_warming", Hidden(warming_c=WARMING_C),
             (Expected("viscosity_drift", "relative_change", -0.25),)),
        Case("probe_delay", Hidden(probe_delay_x_s=150e-6),
             (Expected("channel_delay", "delay_s", 150e-6, channel="x"),)),
        # the frame's own frequency; a fit may place it a little differently with the housing
        # on it, hence 3 %
        Case("frame_mode", Hidden(frame=Frame(mass_kg=100.0, frequency_hz=47.0)),
             (Expected("second_mode", "frequency_hz", 47.0, model_allowance=0.03),)),
        # x dwells identify C_yx, the y force from the x velocity (eq. 7: F_y = C_yx x' + ...)
        Case("film_cross_coupling", Hidden(film_cross_damping_ns_per_m=300.0),
             (Expected("cross_coupling", "c_yx_Ns_per_m", 300.0),)),
        # Bouc-Wen saturates towards F_s where a Dahl/Iwan joint's slip force is reached: the
        # two laws' slip forces agree to about 15 % over 13-38 um
        Case("bouc_wen_seal", Hidden(bouc_wen=bw),
             (Expected("joint_microslip", "slip_force_N", bw.force_n, model_allowance=0.15),)),
        Case("friction_and_cubic", Hidden(seal_friction_n=10.0, cubic_k3_n_per_m3=K3_N_PER_M3),
             (Expected("coulomb_friction", "friction_force_N", 10.0),
              Expected("cubic_stiffness", "k3_N_per_m3", K3_N_PER_M3))),
    ]
    return tuple(out)


@dataclass(frozen=True)
class Signature:
    per_dwell: np.ndarray  # each dwell's signature [noise standard deviations]

    @property
    def per_dwell_max(self) -> float:
        return float(np.max(self.per_dwell))

    @property
    def total(self) -> float:
        return float(np.sqrt(np.sum(self.per_dwell**2)))


def signature(rig: Rig, seed: int, sensors: SensorModel | None = None) -> Signature:
    """The effect's signature beyond a fitted linear rig, from the noise model (module doc)."""
    s = sensors_for(rig, sensors)
    return signature_of(solve_plan(rig, plan(seed)), s)


def signature_of(solved: list[DwellRecord], s: SensorModel) -> Signature:
    rows = []
    for r in solved:
        w = r.omega
        m = {k: s.measured_phasor(k, v, w) for k, v in r.true_fundamentals().items()}
        n_fund = math.sqrt(2.0 / r.n_samples)
        sx, sf, sa, sy = (s.sigma_total(k) * n_fund for k in ("x_m", "fx_N", "ax_mps2", "y_m"))
        x, f, a = m["x_m"], m["fx_N"], m["ax_mps2"]
        h, ratio = f / x, a / x
        y = m["y_m"] * abs(x) / x  # y with the x probe's phase as reference
        sig_h = abs(h) * math.hypot(sf / abs(f), sx / abs(x))
        sig_r = abs(ratio) * math.hypot(sa / abs(a), sx / abs(x))
        rows.append((w, h, ratio, y, sig_h, sig_r, sy))
    omega = np.array([r[0] for r in rows])
    stiff = np.array([r[1] for r in rows])
    sig_stiff = np.array([r[4] for r in rows])
    # K, M from Re H = K - w^2 M; C from Im H = w C; weighted by each dwell's sigma
    a_re = np.column_stack([np.ones_like(omega), -(omega**2)]) / sig_stiff[:, None]
    km = np.linalg.lstsq(a_re, stiff.real / sig_stiff, rcond=None)[0]
    damping = np.sum(omega * stiff.imag / sig_stiff**2) / np.sum(omega**2 / sig_stiff**2)
    fit = km[0] - omega**2 * km[1] + 1j * omega * damping
    res_h = np.abs(stiff - fit) / sig_stiff
    res_r = np.array([abs(r[2] + r[0] ** 2) / r[5] for r in rows])
    res_y = np.array([abs(r[3]) / r[6] for r in rows])
    return Signature(np.sqrt(res_h**2 + res_r**2 + res_y**2))


def threshold_friction(seed: int, sigmas: float = THRESHOLD_SIGMAS) -> float:
    """The seal friction [N] whose largest dwell signature is ``sigmas`` noise deviations (the
    signature is linear in a friction this small: one probe at 1 N, scaled)."""
    probe = signature(Rig(Hidden(seal_friction_n=1.0)), seed).per_dwell_max
    return sigmas / probe


def relative_tolerance(expected: Expected, total_sigmas: float) -> float:
    """The tolerance of a recovered size: three standard deviations of a one-parameter fit to a
    signature of ``total_sigmas`` (relative deviation 1 / total), plus the law's allowance."""
    return 3.0 / total_sigmas + expected.model_allowance


#: the hidden parameter of each size a case with several causes expects (``own_signatures``)
_SIZE_FIELD = {"friction_force_N": "seal_friction_n", "k3_N_per_m3": "cubic_k3_n_per_m3"}


def own_signatures(case: Case, seed: int) -> dict[str, float]:
    """Each expected size's own signature [noise sd] where a case hides several causes: the
    inverse of its relative standard deviation with K, M, C and the other expected sizes fitted
    beside it, on the noise model of ``signature_of`` (each dwell's x dynamic stiffness; the
    sizes' columns are the balance's change over 1 % of each). The run's total signature is
    that of the largest cause: the friction's 2200 sd would size the cubic spring's tolerance
    at 1.1 %, where its own signature is 90 sd (1.1 % for one standard deviation; seeds 1 and
    6201). A case with one cause: its total (``relative_tolerance``)."""
    if len(case.expected) < 2:
        return {}
    fields = [_SIZE_FIELD[e.parameter] for e in case.expected]
    rig = Rig(case.hidden)
    s = sensors_for(rig)
    omega, h0, sig = _stiffness_per_dwell(rig, seed, s)
    cols = [np.concatenate([np.ones_like(omega), 0 * omega]),
            np.concatenate([-(omega**2), 0 * omega]), np.concatenate([0 * omega, omega])]
    for name in fields:
        moved = replace(case.hidden, **{name: 1.01 * getattr(case.hidden, name)})
        _, h1, _ = _stiffness_per_dwell(Rig(moved), seed, s)
        d = (h1 - h0) / 0.01  # per relative unit of the size
        cols.append(np.concatenate([d.real, d.imag]))
    jac = np.column_stack(cols) / np.concatenate([sig, sig])[:, None]
    cov = np.linalg.inv(jac.T @ jac)
    return {e.effect: float(1.0 / math.sqrt(cov[3 + i, 3 + i]))
            for i, e in enumerate(case.expected)}


def _stiffness_per_dwell(rig: Rig, seed: int,
                         s: SensorModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per dwell of ``seed``'s plan: omega, the measured x dynamic stiffness F / X and its
    noise sd (as ``signature_of``)."""
    rows = []
    for r in solve_plan(rig, plan(seed)):
        w = r.omega
        m = {k: s.measured_phasor(k, v, w) for k, v in r.true_fundamentals().items()}
        n_fund = math.sqrt(2.0 / r.n_samples)
        sx, sf = (s.sigma_total(k) * n_fund for k in ("x_m", "fx_N"))
        f, x = m["fx_N"], m["x_m"]
        rows.append((w, f / x, abs(f / x) * math.hypot(sf / abs(f), sx / abs(x))))
    return tuple(np.array([r[i] for r in rows]) for i in range(3))  # type: ignore[return-value]


def generate(case: Case, seed: int) -> Any:
    """The case's recording on ``seed``'s plan (noise seeded from it too)."""
    return record(Rig(case.hidden), plan(seed), seed=seed + 1000)


def judge(case: Case, doc: dict[str, Any], total_sigmas: float,
          own: dict[str, float] | None = None) -> tuple[bool, str]:
    """Whether diagnose's JSON ``doc`` judges ``case`` right, and what it said.

    Clean: no finding, nothing unexplained. Outside the library: no cause with high confidence
    and an honest "unexplained discrepancy" (or "baseline inadequate"). Library effects: every
    hidden cause named with high confidence, nothing else with high confidence, each size within
    ``relative_tolerance`` of the truth (on the size's own signature ``own``, where the case
    hides several causes: ``own_signatures``; else the run's total) and a sensor effect on its
    channel, told apart from exactly the channels ``Expected.alike`` says the data cannot tell
    it from."""
    found = [(f["effect"], f["evidence"].get("confidence")) for f in doc["findings"]]
    confident = {e for e, c in found if c == "high"}
    verdict = doc.get("verdict", {}).get("verdict", "")
    best: dict[str, Any] = next((c for group in doc.get("candidates", []) for c in group[:1]), {})
    said = (f"found {found}, verdict {verdict!r}; best candidate {best.get('effect')} "
            f"{best.get('parameters')}")
    if not case.expected and not case.outside_library:
        return (not found and not doc["unexplained"]), said
    if case.outside_library:
        honest = verdict in ("unexplained discrepancy", "baseline inadequate")
        return (not confident and honest), said
    want = {e.effect for e in case.expected}
    if confident != want:
        return False, said
    for e in case.expected:
        finding = next(f for f in doc["findings"] if f["effect"] == e.effect)
        got = float(finding["parameters"][e.parameter])
        tol = relative_tolerance(e, (own or {}).get(e.effect, total_sigmas))
        if abs(got - e.value) > tol * abs(e.value):
            return False, (f"{said}; {e.parameter} = {got:.4g} (truth {e.value:.4g}, off "
                           f"{got / e.value - 1:+.2%}, tolerance {tol:.2%})")
        if e.channel is not None:
            named = finding["parameters"].get("channel")
            alike = finding["evidence"].get("cannot_tell_from", [])
            if named != e.channel or sorted(alike) != sorted(e.alike):
                return False, (f"{said}; on channel {named} (cannot tell from {alike}; right: "
                               f"{e.channel}, cannot tell from {list(e.alike)})")
    return True, said
