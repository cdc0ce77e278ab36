"""The calibration problem: positions + models + invariants + noise floors, batched.

At rest every position must satisfy (docs/reference.md#rest)

* gyro norm:  |w_hat| = Omega_ie (15.04107 deg/h)
* accel norm: |f_hat| = g_local / g0 (WGS-84 normal gravity, in g)
* dot product (both triads): w_hat . f_hat = Omega_ie * g_local/g0 * sin(latitude)
* slew (both triads, with :class:`recal.detect.slew_data.Slews`): the gyro integrated over the motion
  between windows k and k + 1 carries the gravity direction of window k onto that of window
  k + 1 (2 residuals per slew, rad; :mod:`recal.detect.slew_gravity`)

:meth:`Problem.residuals` evaluates the whitened residuals of all invariants for a *batch* of
parameter vectors, shape (P, D) -> (P, R), in one numpy call. LM uses P = 1, a swarm uses
P = fish x Monte Carlo runs. :meth:`Problem.indicator` is seed 000 eq. (14) (and its accelerometer
twin, seed 002 eq. 18): the RMS over positions of |x_hat|^2 - ref^2 with M - 1 in the denominator.

The problem's parts live beside it, each a base of :class:`Problem` (issue 38): the slews, known
rotations and closed turns (:mod:`recal.solve.problem_motion`), the bias wander's whitening of
the window residuals (:mod:`recal.solve.problem_wander`) and the swarm objective with eq. (14)'s
indicator (:mod:`recal.solve.problem_objective`); this module holds the problem's fields, its
construction, the invariants' structure and evaluation, and the noise propagated to them.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np

from recal.detect.closed_turns import (
    ClosedTurns,
    TurnCandidate,
    closed_turns_of,
    closure_sigma,
    turn_candidates,
)
from recal.detect.known_rotations import KnownRotations
from recal.detect.slew_data import Slews
from recal.detect.slew_gravity import horizontal_basis
from recal.detect.slew_rotation import integrated_rotvec
from recal.errors import RecalInputError
from recal.model.error_model import Model, ParameterLayout
from recal.model.positions import GYRO_STD_COLUMNS, Positions
from recal.model.reference import OMEGA_IE_DEG_H, dot_reference, normal_gravity_g
from recal.model.terms import Term
from recal.solve.problem_motion import MotionInvariants
from recal.solve.problem_objective import (
    LINEAR_INVARIANTS,  # noqa: F401 - recal.problem's name
    ProblemObjective,
)
from recal.solve.problem_wander import WanderWhitening
from recal.solve.wander_covariance import WanderCovariance
from recal.solve.wander_model import WanderModel

#: Residual sigma used before any noise information exists (positions without *_std or *_sem
#: columns): it only sets the relative weight of the invariants for the first fit and is then
#: re-estimated from the residuals. Observability is never decided on it (only structural rank).
PROVISIONAL_SIGMA = {"gyro_norm": 0.01, "accel_norm": 1e-5, "dot": 0.01, "slew": 1e-3,
                     "rotation": 1e-3, "closure": 1e-3}  # fmt: skip
#: Positions.noise_source label -> sigma_source label of the invariants it feeds.
COLUMN_SOURCES = {
    "sem columns": "sem columns",
    "std columns": "std columns (white-noise assumption)",
}
#: sigma_source labels that mean the noise is known from the windows.
KNOWN_SOURCES = frozenset(COLUMN_SOURCES.values()) | {"sem and std columns"}
INVARIANT_SENSORS = {
    "gyro_norm": ("gyro",),
    "accel_norm": ("accel",),
    "dot": ("gyro", "accel"),
    "slew": ("gyro", "accel"),
    "rotation": ("gyro",),
    "closure": ("gyro", "accel"),
}
#: Invariants that need a still gyro: rows of accelerometer-only windows are left out of them.
GYRO_STATIC = frozenset({"gyro_norm", "dot"})


@dataclass(frozen=True)
class Problem(MotionInvariants, WanderWhitening, ProblemObjective):
    """Static-position calibration problem for one or both triads.

    Attributes:
        positions: the static windows.
        models: sensor -> :class:`Model`, in the order gyro, accel.
        latitude_deg, height_m: site, for gravity and the dot-product reference.
        use_dot: include the gyro-accel dot-product invariant when both triads are present.
        sigma: invariant name -> (M,) 1-sigma of the raw residual (|x| - ref, or w.f - ref).
        sigma_source: invariant name -> where sigma comes from: "sem columns" (window standard
            errors, correlated noise included), "std columns (white-noise assumption)"
            (std / sqrt(samples)), "sem and std columns" (a dot product of one of each),
            "provisional" (no noise information yet: relative weights only, never decide on it)
            or "residuals" (re-estimated from a fit).
        ctx: context columns for terms (temperature, time, specific force).
        slews: the gyro increments between windows (:mod:`recal.detect.slew_data`); with both triads they
            add the "slew" invariant (2 residuals per slew, rad). None: no slews.
        slew_earth_rate: take Earth's rotation over each slew out with the calibrated rest rate
            of the first window (a gyro that sees Earth rate); False leaves it in the noise.
        slew_basis: (S, 2, 3) the two directions orthogonal to gravity at each slew's second
            window (at the prior) on which the residual is taken.
        closed_turns: slews taken as whole turns about the vertical (:class:`ClosedTurns`,
            found at the prior by :meth:`build`): the "closure" invariant, 1 residual each, rad.
        turn_candidates: every slew that integrates close to whole turns about the vertical,
            with what was decided and why (:class:`recal.detect.closed_turns.TurnCandidate`).
        slew_excess_rad: an unmodelled error per slew residual added in quadrature to its sigma
            (estimated from the slews' misfit by :func:`recal.solve.slew_fit.slew_excess`), rad.
        wander, wander_cov: the triads' bias wander between windows and the covariance it adds
            to the window residuals (:meth:`with_wander`; state-space form, linear in the
            windows); :meth:`residuals` whitens by it.
    """

    positions: Positions
    models: tuple[Model, ...]
    latitude_deg: float
    height_m: float = 0.0
    use_dot: bool = True
    sigma: Mapping[str, np.ndarray] = field(default_factory=dict)
    sigma_source: Mapping[str, str] = field(default_factory=dict)
    ctx: Mapping[str, np.ndarray] = field(default_factory=dict)
    slews: Slews | None = None
    slew_earth_rate: bool = True
    slew_basis: np.ndarray | None = None
    known_rotations: KnownRotations | None = None
    closed_turns: ClosedTurns | None = None
    turn_candidates: tuple[TurnCandidate, ...] = ()
    slew_excess_rad: float = 0.0
    #: bias wander between windows (:mod:`recal.solve.wander`) and the covariance it adds to the
    #: window invariants' residuals (gyro norm, accel norm, dot: the first Rw of
    #: :meth:`residuals`) in state-space form (a :class:`recal.solve.wander_covariance.WanderCovariance`:
    #: the model and the residuals' sensitivity, never a dense Rw x Rw matrix), set by
    #: :meth:`with_wander`; None: windows independent
    wander: WanderModel | None = None
    wander_cov: WanderCovariance | None = None
    #: the swarm objective (:meth:`objective`): False (the default) the least squares LM
    #: minimises, chi^2 / (R - 1); True seed 000 eq. (14) per invariant over its noise floor
    #: (``--paper``)
    paper_objective: bool = False

    # ---- construction -------------------------------------------------------------------
    @classmethod
    def build(
        cls,
        positions: Positions,
        models: tuple[Model, ...],
        latitude_deg: float,
        height_m: float = 0.0,
        theta_ref: np.ndarray | None = None,
        use_dot: bool = True,
        slews: Slews | None = None,
        slew_earth_rate: bool = True,
        known_rotations: KnownRotations | None = None,
        turn_closure_sigma_deg: float = 0.0,
        slew_excess_rad: float = 0.0,
        gyro_prior_sigma: Mapping[str, np.ndarray] | None = None,
    ) -> Problem:
        """Check the columns the models need, build the context and the noise floors.

        ``theta_ref`` (the prior) is used to propagate the window noise to the invariants and
        to estimate the specific force seen by a gyro g-sensitivity term. ``slews`` add the slew
        invariant when both triads are calibrated (they are ignored otherwise). Slews that are
        closed turns at ``theta_ref`` (:func:`recal.detect.closed_turns.turn_candidates`; none with a
        commanded rotation) add the "closure" invariant, 1 residual each: checked by the two
        windows' Earth-rate headings (at ``theta_ref``, with the gyro's prior 1-sigma
        ``gyro_prior_sigma``: "gyro.bias" deg/h and "gyro.scale" in the scale's units, (3,)
        each; None: the terms' typical changes), or, where the heading is not observable,
        declared with the 1-sigma ``turn_closure_sigma_deg`` (<= 0: none declared).
        ``slew_excess_rad`` is added in quadrature to every slew residual's sigma (an
        unmodelled per-slew error).
        """
        sensors = [m.sensor for m in models]
        for s in sensors:
            if not getattr(positions, f"has_{s}"):
                raise RecalInputError(f"{positions.source}: no {s}_x/y/z columns for --sensor {s}")
        still = positions.columns.get("gyro_still")
        if sensors == ["gyro"] and still is not None and not (still != 0).any():
            raise RecalInputError(
                f"{positions.source}: the gyro was still in no window (gyro_still 0 in every "
                "row: a unit held by hand); calibrate it from the slews, with both triads"
            )
        ctx: dict[str, np.ndarray] = {}
        needs = frozenset().union(*(m.needs for m in models))
        for col in ("temperature_c", "temperature_rate_c_per_h"):
            if col in needs:
                if col not in positions.columns:
                    users = [t.name for m in models for t in m.terms if col in t.needs]
                    raise RecalInputError(
                        f"{positions.source}: effect {', '.join(users)} needs the '{col}' column"
                    )
                ctx[col] = positions.columns[col]
        if "time_h" in needs:
            if "start_s" not in positions.columns or "end_s" not in positions.columns:
                raise RecalInputError(f"{positions.source}: bias drift needs start_s and end_s")
            ctx["time_h"] = 0.5 * (positions.columns["start_s"] + positions.columns["end_s"]) / 3600
        use_slews = slews is not None and len(slews) > 0 and set(sensors) == {"gyro", "accel"}
        if use_slews:
            bad = [
                t.name
                for t in models[sensors.index("gyro")].terms
                if type(t).nonlinear is not Term.nonlinear
            ]
            if bad:
                raise RecalInputError(f"slews: effect {', '.join(bad)} depends on the rate")
        prob = cls(
            positions, tuple(models), latitude_deg, height_m, use_dot, {}, "provisional", ctx,
            slews if use_slews else None, slew_earth_rate,
        )  # fmt: skip
        layout = prob.layout
        theta = layout.neutral() if theta_ref is None else np.asarray(theta_ref, float)
        if "specific_force_g" in needs:
            if "accel" not in sensors and not positions.has_accel:
                raise RecalInputError("gyro.g_sensitivity needs accel columns in the positions")
            ctx["specific_force_g"] = prob._specific_force(theta)
        if use_slews:
            f = prob._specific_force(theta)
            prob = replace(prob, slew_basis=horizontal_basis(f[slews.second]))
            if known_rotations is not None:
                on = np.isin(known_rotations.slew, slews.first)
                if on.any():
                    kr = KnownRotations(known_rotations.slew[on], known_rotations.rotvec[on],
                                        known_rotations.sigma_rad[on])  # fmt: skip
                    prob = replace(prob, known_rotations=kr)
            gain, A, offset = prob._gyro_parts(theta)
            rv = integrated_rotvec(slews, gain, A, offset, prob._zero_rate)[0]
            known = np.zeros(len(slews), bool)
            if prob.known_rotations is not None:
                known = np.isin(slews.first, prob.known_rotations.slew)
            check = prob._heading_check(theta, f, gyro_prior_sigma)
            found = turn_candidates(slews, rv, f[slews.first], f[slews.second],
                                    turn_closure_sigma_deg, known, check)  # fmt: skip
            prob = replace(prob, closed_turns=closed_turns_of(found, f[slews.first]),
                           turn_candidates=tuple(found), slew_excess_rad=float(slew_excess_rad))  # fmt: skip
        return prob.with_sigma(*prob.propagated_sigma(theta))

    def _specific_force(self, theta: np.ndarray) -> np.ndarray:
        if "accel" in self.sensors:
            sl = self.layout.model_slices()["accel"]
            return self.model("accel").inverse(theta[None, sl], self.positions.accel, self.ctx)[0]
        acc = self.positions.accel  # nominal: unit-gravity direction from raw outputs
        return acc / np.linalg.norm(acc, axis=1, keepdims=True) * self.gravity_g

    def with_sigma(self, sigma: Mapping[str, np.ndarray], source: Mapping[str, str]) -> Problem:
        return replace(self, sigma=dict(sigma), sigma_source=dict(source))

    @property
    def noise_known(self) -> bool:
        """True when every invariant's sigma comes from the windows' std or sem columns."""
        return all(self.noise_known_for(n) for n in self.sigma_source)

    def noise_known_for(self, name: str) -> bool:
        """True when invariant ``name``'s sigma comes from the windows' noise columns."""
        return self.sigma_source.get(name) in KNOWN_SOURCES

    # ---- structure ----------------------------------------------------------------------
    @property
    def sensors(self) -> tuple[str, ...]:
        return tuple(m.sensor for m in self.models)

    def model(self, sensor: str) -> Model:
        return next(m for m in self.models if m.sensor == sensor)

    @cached_property
    def layout(self) -> ParameterLayout:
        return ParameterLayout(self.models)

    @cached_property
    def _slices(self) -> dict[str, slice]:
        return self.layout.model_slices()

    @property
    def M(self) -> int:
        return len(self.positions)

    @property
    def gravity_g(self) -> float:
        return normal_gravity_g(self.latitude_deg, self.height_m)

    @property
    def invariant_names(self) -> tuple[str, ...]:
        names = [f"{s}_norm" for s in self.sensors]
        if self.use_dot and len(self.sensors) == 2:
            names.append("dot")
        if self.gyro_rows is not None and self.gyro_rows.size == 0:  # no still gyro anywhere
            names = [n for n in names if n not in GYRO_STATIC]
        if "dot" in names and self.rows_of("dot").size == 0:  # no window's vertical rate seen
            names.remove("dot")
        if self.slews is not None:
            names.append("slew")
            if self.known_rotations is not None:
                names.append("rotation")
            if self.closed_turns is not None:
                names.append("closure")
        return tuple(names)

    @cached_property
    def gyro_rows(self) -> np.ndarray | None:
        """Positions whose gyro was still (column ``gyro_still`` not 0), or None for all.

        An accelerometer-only window (a pose held by hand: the gyro trembles) serves the accel
        norm and stays a slew endpoint, but its gyro mean is no static reading: the gyro norm
        and the dot product leave it out (docs/static.md, "Per-triad stillness").
        """
        col = self.positions.columns.get("gyro_still")
        if col is None or (col != 0).all():
            return None
        return np.flatnonzero(col != 0)

    @cached_property
    def vertical_free(self) -> np.ndarray:
        """(M,) True where a window's gyro rate along gravity is no measurement (column
        ``gyro_vertical`` 0: a hull's heading creep, unknown without the ship's heading, sits in
        it like a bias; recal.detect.creep). Its gyro norm is then taken across gravity,
        against Earth's horizontal rate, and the dot product leaves it out: the creep moves
        neither, and the accelerometer and the horizontal rate still count."""
        col = self.positions.columns.get("gyro_vertical")
        if col is None or not {"gyro", "accel"} <= set(self.sensors):
            return np.zeros(self.M, dtype=bool)
        return np.asarray(col, float) == 0

    @cached_property
    def latitudes_deg(self) -> np.ndarray:
        """(M,) each window's latitude, deg: column ``latitude_deg`` (the ship's GNSS, means
        over the window) where finite, else the site's ``latitude_deg``."""
        col = self.positions.columns.get("latitude_deg")
        lat = np.full(self.M, float(self.latitude_deg))
        if col is not None:
            col = np.asarray(col, float)
            lat = np.where(np.isfinite(col), col, lat)
        return lat

    def rows_of(self, name: str) -> np.ndarray:
        """The position (row) of each residual of a per-position invariant."""
        rows = np.arange(self.M)
        if name in GYRO_STATIC and self.gyro_rows is not None:
            rows = self.gyro_rows
        if name == "dot" and self.vertical_free.any():
            rows = rows[~self.vertical_free[rows]]
        return rows

    def n_of(self, name: str) -> int:
        """Residuals of invariant ``name``: one per position (the gyro norm and dot product:
        per position whose gyro was still), two per slew, three per known rotation."""
        if name == "slew" and self.slews is not None:
            return 2 * len(self.slews)
        if name == "rotation" and self.known_rotations is not None:
            return 3 * len(self.known_rotations)
        if name == "closure" and self.closed_turns is not None:
            return len(self.closed_turns)
        return int(self.rows_of(name).shape[0])

    def reference(self, name: str) -> float | np.ndarray:
        """What invariant ``name`` reads at rest: a float, or (n_of(name),) per window where the
        windows' latitudes differ (:attr:`latitudes_deg`) or a gyro norm is taken across
        gravity (:attr:`vertical_free`: Earth's horizontal rate)."""
        if name in ("slew", "rotation", "closure"):
            return 0.0
        rows = self.rows_of(name)
        lat = self.latitudes_deg[rows]
        uniform = bool(np.all(lat == self.latitude_deg))
        if name == "gyro_norm":
            free = self.vertical_free[rows]
            if not free.any():
                return OMEGA_IE_DEG_H
            return np.where(free, OMEGA_IE_DEG_H * np.cos(np.radians(lat)), OMEGA_IE_DEG_H)
        if name == "accel_norm":
            if uniform:
                return self.gravity_g
            return np.array([normal_gravity_g(float(v), self.height_m) for v in lat])
        if uniform:
            return dot_reference(self.latitude_deg, self.height_m)
        return np.array([dot_reference(float(v), self.height_m) for v in lat])

    @property
    def n_residuals(self) -> int:
        return sum(self.n_of(n) for n in self.invariant_names)

    def output(self, sensor: str) -> np.ndarray:
        return self.positions.gyro if sensor == "gyro" else self.positions.accel

    # ---- evaluation (batched) -----------------------------------------------------------
    def physical(self, theta: np.ndarray) -> dict[str, np.ndarray]:
        """theta (P, D) -> sensor -> estimated true inputs (P, M, 3)."""
        return {s: np.moveaxis(c, 0, -1) for s, c in self._components(theta).items()}

    def _components(self, theta: np.ndarray) -> dict[str, np.ndarray]:
        """sensor -> true inputs, component-major (3, P, M)."""
        theta = np.atleast_2d(theta)
        sl = self._slices
        return {
            m.sensor: m.inverse_components(
                theta[:, sl[m.sensor]], self._outputs[m.sensor], self.ctx
            )
            for m in self.models
        }

    @cached_property
    def _outputs(self) -> dict[str, np.ndarray]:
        return {s: self.output(s) for s in self.sensors}

    def _invariant_values(self, theta: np.ndarray, squared: bool) -> dict[str, np.ndarray]:
        """|x|^2 (squared) or |x| per triad, and w.f, each (P, M)."""
        x = self._components(theta)
        out = {}
        for name in self.invariant_names:
            if name == "slew":
                out[name] = self._slew_values(theta, x)
            elif name == "rotation":
                out[name] = self._rotation_values(theta)
            elif name == "closure":
                out[name] = self._closure_values(theta)
            elif name == "dot":
                rows = self.rows_of(name)
                out[name] = np.einsum("ipm,ipm->pm", x["gyro"][..., rows], x["accel"][..., rows])
            else:
                rows = self.rows_of(name)
                v = x[name.split("_")[0]][..., rows]
                sq = np.einsum("ipm,ipm->pm", v, v)
                free = self.vertical_free[rows] if name == "gyro_norm" else None
                if free is not None and free.any():  # across gravity: the creep is along it
                    f = x["accel"][..., rows]
                    vf = np.einsum("ipm,ipm->pm", v, f)
                    ff = np.maximum(np.einsum("ipm,ipm->pm", f, f), 1e-300)
                    sq = np.where(free, np.maximum(sq - vf**2 / ff, 0.0), sq)
                out[name] = sq if squared else np.sqrt(sq)
        return out

    def norm_gradients(self, name: str, x: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """d |x| / d x per triad (M, 3) of norm invariant ``name`` at the inputs ``x`` (sensor ->
        (M, 3)), all positions: the unit vector; for a gyro norm taken across gravity
        (:attr:`vertical_free`) the horizontal unit vector, and the specific force's share."""
        sensor = name.split("_")[0]
        v = x[sensor]
        out = {sensor: v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-300)}
        free = self.vertical_free if name == "gyro_norm" else np.zeros(self.M, dtype=bool)
        if free.any():
            f = x["accel"]
            fn = np.maximum(np.linalg.norm(f, axis=1, keepdims=True), 1e-300)
            u = f / fn
            vv = np.sum(v * u, axis=1, keepdims=True)
            vh = v - vv * u
            h = np.maximum(np.linalg.norm(vh, axis=1, keepdims=True), 1e-300)
            out["gyro"] = np.where(free[:, None], vh / h, out["gyro"])
            out["accel"] = np.where(free[:, None], -vv / (h * fn) * vh, 0.0)
        return out

    def raw_residuals(self, theta: np.ndarray) -> dict[str, np.ndarray]:
        """Invariant name -> (P, M) raw residual: |x| - ref, or w.f - ref (input units); the
        slew invariant (P, 2 S), rad."""
        vals = self._invariant_values(theta, squared=False)
        return {n: v - self.reference(n) for n, v in vals.items()}

    def residuals(self, theta: np.ndarray) -> np.ndarray:
        """Whitened residuals (P, R), R = M x number of invariants, for least squares. With a
        bias wander (:meth:`with_wander`) the window invariants are whitened together: each is
        replaced by its standardised Kalman innovation under the wander (the inverse Cholesky
        factor of their full covariance, windows in time order: a generalised least squares),
        in time and memory linear in the windows; the other invariants are left as they are."""
        raw = self.raw_residuals(theta)
        parts = [raw[n] / self.sigma[n] for n in self.invariant_names]
        W = self._whitener
        if W is None:
            return np.concatenate(parts, axis=1)
        k = len(self.window_invariants)
        return np.concatenate([W.apply(np.concatenate(parts[:k], axis=1)), *parts[k:]], axis=1)

    # ---- noise --------------------------------------------------------------------------
    def propagated_sigma(self, theta: np.ndarray) -> tuple[dict[str, np.ndarray], dict[str, str]]:
        """Window-mean noise (:meth:`Positions.std_of_mean`: *_sem columns, else *_std /
        sqrt(samples)) propagated to each invariant at ``theta``.

        Falls back to :data:`PROVISIONAL_SIGMA` when a triad has neither; the caller then
        re-estimates the noise from the residuals (:meth:`with_sigma_from_residuals`).
        """
        x = {k: v[0] for k, v in self.physical(theta[None]).items()}
        sd_in: dict[str, np.ndarray | None] = {}
        gains = self._output_gains(theta, x)
        kind: dict[str, str] = {}
        for m in self.models:
            sd = self.positions.std_of_mean(m.sensor)
            kind[m.sensor] = COLUMN_SOURCES.get(self.positions.noise_source(m.sensor) or "", "")
            if sd is not None:
                sd = sd / gains[m.sensor]  # output noise -> input units
            sd_in[m.sensor] = sd
        out, source = {}, {}
        for n in self.invariant_names:
            needed = INVARIANT_SENSORS[n]
            motion = ("slew", "rotation", "closure")
            slew_sd = self._slew_sigma(x, sd_in, gains) if n in motion else None
            if n == "rotation" and slew_sd is not None:
                slew_sd = self._rotation_sigma(sd_in, gains)
            if n == "closure" and slew_sd is not None:
                assert self.slews is not None and self.closed_turns is not None
                std_in = self.positions.stack(GYRO_STD_COLUMNS) / gains["gyro"]
                slew_sd = closure_sigma(self.slews, self.closed_turns, std_in, self.slew_earth_rate)
            if any(sd_in[s] is None for s in needed) or (n in motion and slew_sd is None):
                out[n] = np.full(self.n_of(n), PROVISIONAL_SIGMA[n])
                source[n] = "provisional"
                continue
            kinds = {kind[s] for s in needed}
            source[n] = kinds.pop() if len(kinds) == 1 else "sem and std columns"
            if n in motion:
                out[n] = slew_sd
                continue
            if n == "dot":
                w, f = x["gyro"], x["accel"]
                var = np.sum(f**2 * sd_in["gyro"] ** 2 + w**2 * sd_in["accel"] ** 2, axis=1)
            else:
                grads = self.norm_gradients(n, x)
                var = sum(
                    np.sum(g**2 * sd_in[s] ** 2, axis=1)
                    for s, g in grads.items()
                    if sd_in.get(s) is not None
                )
            out[n] = np.sqrt(np.maximum(var[self.rows_of(n)], 1e-300))
        return out, source

    def _output_gains(
        self, theta: np.ndarray, x: Mapping[str, np.ndarray]
    ) -> dict[str, np.ndarray]:
        """sensor -> (M, 3) local gain d N / d x (output per input unit, ~ K_eff) at ``theta``."""
        sl = self.layout.model_slices()
        gains = {}
        for m in self.models:
            step = np.abs(x[m.sensor]) * 1e-6 + 1e-9
            th = theta[None, sl[m.sensor]]
            gain = (
                m.forward(th, x[m.sensor] + step, self.ctx)[0]
                - m.forward(th, x[m.sensor], self.ctx)[0]
            ) / step
            gains[m.sensor] = np.maximum(np.abs(gain), 1e-300)
        return gains

    def at(self, theta: np.ndarray) -> Problem:
        """The problem re-referenced at ``theta`` (an estimate rather than the prior): the window
        noise propagated through it and the slews' horizontal basis taken from it. Sigmas that
        came from fit residuals are kept. A fit iterated with this is a fixed point: calibrating
        again with its own output as the prior builds the same problem."""
        prob = self
        if self.slews is not None:
            f = self._specific_force(theta)
            prob = replace(prob, slew_basis=horizontal_basis(f[self.slews.second]))
        sigma, source = prob.propagated_sigma(theta)
        keep = {n for n in self.sigma_source if not self.noise_known_for(n)}
        sigma = {n: (self.sigma[n] if n in keep else v) for n, v in sigma.items()}
        source = {n: (self.sigma_source[n] if n in keep else v) for n, v in source.items()}
        prob = prob.with_sigma(sigma, source)
        return prob.with_wander(self.wander, theta) if self.wander is not None else prob

    def with_sigma_from_residuals(self, theta: np.ndarray, n_params: int) -> Problem:
        """Replace every sigma not known from noise columns by the dof-corrected residual RMS."""
        raw = self.raw_residuals(theta[None])
        dof_frac = max(1.0 - n_params / max(self.n_residuals, 1), 0.05)
        out, source = dict(self.sigma), dict(self.sigma_source)
        for n, r in raw.items():
            if self.noise_known_for(n):
                continue
            rms = float(np.sqrt(np.mean(r[0] ** 2) / dof_frac))
            ref = float(np.max(np.abs(self.reference(n))))
            out[n] = np.full(r.shape[1], max(rms, 1e-12 * ref + 1e-300))
            source[n] = "residuals"
        return self.with_sigma(out, source)
