"""Bias wander's types (:mod:`recal.solve.wander`): a triad's Gauss-Markov wander
(:class:`TriadWander`), a model of each triad's (:class:`WanderModel`) and its JSON, the windows'
times and sessions the wander is sampled at, and the wander a drift test allows for
(:func:`possible_wander`)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from recal.errors import RecalInputError


@dataclass(frozen=True)
class TriadWander:
    """One triad's bias wander: steady-state 1-sigma per axis (output units) and correlation
    time per axis, s (0: independent windows; inf: a constant offset shared by every window)."""

    sigma: np.ndarray  # (3,)
    tau_s: np.ndarray  # (3,)

    def __post_init__(self) -> None:
        s = np.asarray(self.sigma, float).reshape(-1)
        t = np.asarray(self.tau_s, float).reshape(-1)
        if s.shape != (3,) or t.shape != (3,):
            raise RecalInputError("a triad's wander needs 3 sigmas and 3 correlation times")
        if not (np.all(np.isfinite(s)) and np.all(s >= 0) and np.all(t >= 0)):
            raise RecalInputError("wander sigmas must be finite and >= 0, correlation times >= 0")
        object.__setattr__(self, "sigma", s)
        object.__setattr__(self, "tau_s", t)


@dataclass(frozen=True)
class WanderModel:
    """Bias wander of each triad between windows (sensor -> :class:`TriadWander`), and where
    it came from ("estimated from the residuals", "given", ...). ``unproven``: the triads
    carried although their test did not keep them (recal.solve.wander_fit.carry_unproven):
    in the covariance, never claimed as wander."""

    triads: Mapping[str, TriadWander] = field(default_factory=dict)
    source: str = "given"
    notes: tuple[str, ...] = ()
    unproven: frozenset[str] = frozenset()

    @property
    def empty(self) -> bool:
        return not any(np.any(t.sigma > 0) for t in self.triads.values())

    def to_json_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"kind": "gauss-markov", "source": self.source}
        for s, t in self.triads.items():
            out[s] = {
                "sigma": [float(v) for v in t.sigma],
                "tau_s": [float(v) if math.isfinite(v) else None for v in t.tau_s],
                **({"significant": False} if s in self.unproven else {}),
            }
        if self.notes:
            out["notes"] = list(self.notes)
        return out

    @classmethod
    def from_json_dict(cls, data: Mapping[str, Any], source: str = "given") -> WanderModel:
        """The ``"wander"`` block of a noise file or of calibrate's JSON (sensor -> {"sigma",
        "tau_s"}, output units and s; a null tau is infinite)."""
        if not isinstance(data, Mapping):
            raise RecalInputError("a wander model must be a JSON object")
        triads, unproven = {}, set()
        for s in ("gyro", "accel"):
            block = data.get(s)
            if block is None:
                continue
            if isinstance(block, Mapping) and block.get("significant") is False:
                unproven.add(s)
            try:
                tau = [math.inf if v is None else float(v) for v in block["tau_s"]]
                triads[s] = TriadWander(np.array(block["sigma"], float), np.array(tau))
            except (KeyError, TypeError, ValueError) as exc:
                raise RecalInputError(
                    f"wander model, {s}: needs 'sigma' and 'tau_s' ({exc})"
                ) from exc
        notes = tuple(str(n) for n in data.get("notes") or ())
        return cls(triads, str(data.get("source", source)), notes, frozenset(unproven))


def window_times(columns: Mapping[str, np.ndarray], M: int) -> np.ndarray | None:
    """The windows' mid-times, s (None without start_s and end_s: times unknown)."""
    if "start_s" not in columns or "end_s" not in columns:
        return None
    t = 0.5 * (np.asarray(columns["start_s"], float) + np.asarray(columns["end_s"], float))
    return t if t.shape == (M,) and np.all(np.isfinite(t)) else None


def window_sessions(columns: Mapping[str, np.ndarray], M: int) -> np.ndarray | None:
    """The windows' ``session`` column (each session restarts the device clock: windows of two
    sessions are not correlated by their times), or None (one session)."""
    s = columns.get("session")
    if s is None:
        return None
    s = np.asarray(s, float)
    return s if s.shape == (M,) else None


def possible_wander(noise_model: Mapping[str, Any] | None) -> WanderModel | None:
    """The wander a test that must not read wander as a change allows for: every triad the
    estimate tested, kept or not, at the one-sided 95 % upper bound of its sigma
    (:data:`SIGMA_UPPER_DELTA`) and its conservative correlation time; a given model as given.

    A calibration keeps a triad's wander only when it is significant, and at its best sigma,
    which keeps its own sigmas sharp; a drift test must instead cover the wander the windows
    could hold. Measured on 40 units with wander at 0.5-6 times the window noise, tau 1-24 h
    (benchmarks/bench_wander.py): with the kept model at its best sigma 13 of 40 unchanged units
    alarmed (4.0 expected at the configured rate; 2 with the simulated wander given). Reads a
    calibration's ``noise_model`` (its ``"wander"`` block and ``"wander_test"`` list)."""
    if not noise_model:
        return None
    block = noise_model.get("wander")
    model = WanderModel.from_json_dict(block, "the accepted version") if block else WanderModel()
    triads = dict(model.triads)
    tests = noise_model.get("wander_test")
    for test in tests if isinstance(tests, list) else ():
        s, tau = test.get("sensor"), test.get("tau_s")
        sigma = max(float(test.get("sigma") or 0.0), float(test.get("sigma_upper") or 0.0))
        if s in ("gyro", "accel") and sigma > 0 and tau is not None:
            triads[s] = TriadWander(np.full(3, sigma), np.full(3, float(tau)))
    if not triads:
        return None
    return WanderModel(triads, "the accepted version's, each triad at its upper bound")
