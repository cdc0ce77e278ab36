"""The drift test's windows at the accepted coefficients: which triads can be tested and
their model (:func:`accepted_model`), the invariant residuals (:func:`invariants`), and their
noise and sensitivity to each output (:func:`noise_and_sensitivity`)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from recal.errors import RecalInputError
from recal.model.coefficients import CoefficientSet
from recal.model.error_model import Model, ParameterLayout
from recal.model.positions import Positions
from recal.model.reference import OMEGA_IE_DEG_H, dot_reference, normal_gravity_g

#: Invariants of one window, in the order of the rows of A_k, R_k and r_k.
INVARIANTS = ("gyro_norm", "accel_norm", "dot")
#: Coefficients a triad must have to be tested (the others default to neutral).
REQUIRED_TERMS = ("scale", "bias")


def accepted_model(
    positions: Positions, coefficients: CoefficientSet, notes: list[str]
) -> tuple[tuple[str, ...], tuple[Model, ...], ParameterLayout, np.ndarray]:
    """The triads ``positions`` can test against ``coefficients`` (gyro first), their models
    (the seed terms plus the effects the coefficients carry), the flat layout and the accepted
    coefficients as a vector in it. Raises RecalInputError when nothing can be tested."""
    from recal.solve.calibrate import build_models

    sensors = _tested_sensors(positions, coefficients, notes)
    seed = {f"{s}.{k}" for s in sensors for k in ("scale", "bias", "misalignment", "quadratic")}
    effects = [n for n in coefficients.values if n not in seed and n.split(".")[0] in sensors]
    models = build_models(sensors, effects, [], coefficients.t0_c)
    layout = ParameterLayout(models)
    return sensors, models, layout, coefficients.to_vector(layout)


def _tested_sensors(
    positions: Positions, coefficients: CoefficientSet, notes: list[str]
) -> tuple[str, ...]:
    """Triads present in the positions and complete in the coefficients, gyro first."""
    source = coefficients.metadata.get("source", "coefficients")
    sensors = []
    for s in ("gyro", "accel"):
        if not getattr(positions, f"has_{s}"):
            continue
        have = [k for k in REQUIRED_TERMS if coefficients.get(f"{s}.{k}") is not None]
        if not have:
            notes.append(f"{s} not tested: {source} has no {s} coefficients")
            continue
        if len(have) < len(REQUIRED_TERMS):
            missing = ", ".join(f"{s}.{k}" for k in REQUIRED_TERMS if k not in have)
            raise RecalInputError(f"{source}: {missing} missing (needed to test the {s} triad)")
        sensors.append(s)
    if not sensors:
        present = [s for s in ("gyro", "accel") if getattr(positions, f"has_{s}")]
        raise RecalInputError(
            f"{source} has no coefficients for the triad(s) in {positions.source} "
            f"({', '.join(present)})"
        )
    for s in sensors:
        if positions.noise_source(s) is None:
            raise RecalInputError(
                f"{positions.source}: no {s}_x/y/z_sem or _std columns: the drift test needs "
                "each window's own noise"
            )
    return tuple(sensors)


def invariants(
    x: dict[str, np.ndarray],
    sensors: Sequence[str],
    lat: np.ndarray,
    h: float,
    free: np.ndarray | None = None,
) -> np.ndarray:
    """(P, M, 3) residuals |w| - Omega, |f| - g, w.f - ref (0 where a triad is missing); ``lat``
    (M,) each window's latitude, deg. Where ``free`` (M,), the window's vertical rate is no
    measurement (recal.detect.creep): the gyro's residual is its rate across gravity less
    Earth's horizontal rate (the dot product is then left out by the caller)."""
    some = next(iter(x.values()))
    out = np.zeros(some.shape[:2] + (3,))
    lat = np.broadcast_to(np.asarray(lat, float), some.shape[1:2])
    g = np.array([normal_gravity_g(float(v), h) for v in lat])
    if "gyro" in x:
        w = x["gyro"]
        ref = np.full(len(lat), OMEGA_IE_DEG_H)
        sq = np.sum(w * w, axis=-1)
        if free is not None and free.any() and "accel" in x:
            f = x["accel"]
            vf = np.sum(w * f, axis=-1)
            sq = np.where(free, np.maximum(sq - vf**2 / np.sum(f * f, axis=-1), 0.0), sq)
            ref = np.where(free, OMEGA_IE_DEG_H * np.cos(np.radians(lat)), ref)
        out[..., 0] = np.sqrt(sq) - ref
    if "accel" in x:
        out[..., 1] = np.linalg.norm(x["accel"], axis=-1) - g
    if len(sensors) == 2:
        dot_ref = np.array([dot_reference(float(v), h) for v in lat])
        out[..., 2] = np.einsum("pmi,pmi->pm", x["gyro"], x["accel"]) - dot_ref
    return out


def noise_and_sensitivity(
    problem, theta: np.ndarray, x: dict[str, np.ndarray], sensors
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """(M, 3, 3) covariance of the window residuals from each window's standard errors, and
    sensor -> (M, 3, 3) d residual / d output of each axis (the wander's way in).

    The output noise (M, 3) goes to input units through the inverse model's own Jacobian
    d x / d N (per window, by central differences on all windows at once), then to the
    invariants: d|x| = u . dx and d(w . f) = f . dw + w . df."""
    M = problem.M
    sl = problem.layout.model_slices()
    J = np.zeros((M, 3, 6))  # d invariants / d (input gyro, input accel)
    cov_in = np.zeros((M, 6, 6))
    dxdn_of: dict[str, np.ndarray] = {}
    for i, s in enumerate(("gyro", "accel")):
        if s not in sensors:
            continue
        m = problem.model(s)
        v = x[s][0]  # (M, 3)
        sem = problem.positions.std_of_mean(s)
        out = problem.output(s)
        h = np.maximum(np.abs(out), 1e-12) * 1e-6
        dxdn = np.empty((M, 3, 3))
        for a in range(3):
            up, dn = out.copy(), out.copy()
            up[:, a] += h[:, a]
            dn[:, a] -= h[:, a]
            th = theta[None, sl[s]]
            dxdn[:, :, a] = (
                m.inverse(th, up, problem.ctx)[0] - m.inverse(th, dn, problem.ctx)[0]
            ) / (2 * h[:, a, None])
        dxdn_of[s] = dxdn
        cov_in[:, 3 * i : 3 * i + 3, 3 * i : 3 * i + 3] = np.einsum(
            "mia,ma,mja->mij", dxdn, sem**2, dxdn
        )
        J[:, i, 3 * i : 3 * i + 3] = v / np.linalg.norm(v, axis=1, keepdims=True)
    if len(sensors) == 2:
        J[:, 2, :3] = x["accel"][0]
        J[:, 2, 3:] = x["gyro"][0]
        grads = problem.norm_gradients("gyro_norm", {s: x[s][0] for s in sensors})
        J[:, 0, :3] = grads["gyro"]  # across gravity where the vertical rate is free
        if "accel" in grads:
            J[:, 0, 3:] = grads["accel"]
    sens = {
        s: np.einsum("mia,mab->mib", J[:, :, 3 * i : 3 * i + 3], dxdn_of[s])
        for i, s in enumerate(("gyro", "accel"))
        if s in dxdn_of
    }
    return np.einsum("mia,mab,mjb->mij", J, cov_in, J), sens
