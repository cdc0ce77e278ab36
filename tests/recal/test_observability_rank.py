"""Rank decides, not counting (docs/reference.md#norms): priority order, exactly determined designs,
and no R x R matrix on the way."""

import tracemalloc

import numpy as np
import pytest

from recal.model.coefficients import CoefficientSet
from recal.model.error_model import Model, ParameterLayout
from recal.model.positions import Positions
from recal.model.reference import normal_gravity_g
from recal.sim.simulate import simulate_positions, truth_model
from recal.solve.calibrate import calibrate
from recal.solve.observability import INFO_MIN, ROTATION_REASON, analyze, jacobian
from recal.solve.options import CalibrationOptions
from recal.solve.problem import Problem

LAT = 45.0


def six_faces(
    truth: CoefficientSet, sigma_g: float = 5e-6, seed: int = 0, noise_columns: bool = True
) -> Positions:
    """Accelerometer on its six faces (+-x, +-y, +-z), window-mean noise ``sigma_g`` (g)."""
    theta, model = truth_model(truth, "accel")
    f = np.vstack([np.eye(3), -np.eye(3)]) * normal_gravity_g(LAT, 0.0)
    K = theta[0, :3]
    rng = np.random.default_rng(seed)
    out = model.forward(theta, f, {})[0] + rng.normal(size=(6, 3)) * sigma_g * K
    cols = {"start_s": np.arange(6) * 90.0, "end_s": np.arange(6) * 90.0 + 60, "samples": [6e3] * 6}
    for i, a in enumerate("xyz"):
        cols[f"accel_{a}"] = out[:, i]
        if noise_columns:
            cols[f"accel_{a}_sem"] = np.full(6, sigma_g * K[i])
    return Positions.from_columns(cols)


@pytest.mark.parametrize("noise_columns", [True, False])
def test_six_faces_estimate_scale_and_bias_and_hold_the_rest(noise_columns):
    truth = CoefficientSet.seed_truth()
    res = calibrate(six_faces(truth, noise_columns=noise_columns), CalibrationOptions("accel"))
    status = res.to_json_dict()["status"]["accel"]
    assert status["scale"] == ["estimated"] * 3 and status["bias"] == ["estimated"] * 3
    assert set(status["misalignment"].values()) == {"held"}
    assert status["quadratic"] == ["held"] * 3
    rep = res.observability
    assert rep.rank == 6 and rep.redundancy == 0
    # the held part stays at the prior (data-derived: zero misalignment and K2) ...
    assert np.all(res.coefficients.values["accel.misalignment"] == 0)
    assert np.all(res.coefficients.values["accel.quadratic"] == 0)
    # ... so six faces see K exactly and b + K2 g^2 (b and K2 enter the same way)
    g = normal_gravity_g(LAT, 0.0)
    seen_bias = truth.values["accel.bias"] + truth.values["accel.quadratic"] * g**2
    K, b = res.coefficients.values["accel.scale"], res.coefficients.values["accel.bias"]
    assert np.allclose(K, truth.values["accel.scale"], rtol=5e-5)
    assert np.allclose(b, seen_bias, atol=5e-5)
    notes = " ".join(res.notes)
    assert "exactly determined" in notes and "cannot check" in notes
    # 3 rotations (never visible to a norm) + 3 misalignment sums + 3 K2, each with its reason
    assert "held at the prior (6 direction(s)" in notes and "accel.quadratic.K2x" in notes
    assert len(res.observability.held_reasons) == 9
    assert res.to_json_dict()["chi2_red"] is None  # no redundancy: chi2 says nothing
    sd = res.uncertainty["accel.scale"]
    if noise_columns:
        assert np.all(np.isfinite(sd) & (sd > 0) & (sd < 1e-5))
    else:
        assert np.all(np.isnan(sd)) and "unknown" in res.to_json_dict()["uncertainty_kind"]


def test_bias_is_preferred_over_the_quadratic_term_it_trades_with():
    """Twelve faces (six, twice): redundancy, but b and K2 still enter identically."""
    truth = CoefficientSet.seed_truth()
    a, b = six_faces(truth, seed=1), six_faces(truth, seed=2)
    pos = Positions.from_columns(
        {k: np.concatenate([a.columns[k], b.columns[k]]) for k in a.columns}
    )
    res = calibrate(pos, CalibrationOptions("accel"))
    rep = res.observability
    assert rep.rank == 6 and rep.redundancy == 6
    k2 = [i for i, n in enumerate(rep.names) if ".quadratic." in n]
    assert not rep.estimated[k2].any()
    reasons = [r for d, r in zip(rep.held_directions, rep.held_reasons) if "quadratic" in d]
    assert len(reasons) == 3 and all("acts like scale and bias" in r for r in reasons)


@pytest.mark.parametrize(
    ("design", "sensors"), [("24", ("gyro",)), ("random", ("accel",)), ("24", ("gyro", "accel"))]
)
def test_rich_designs_keep_the_plain_svd_observable_span(design, sensors):
    truth = CoefficientSet.seed_truth()
    pos = simulate_positions(truth, design, 30 if design == "random" else None, sensors=sensors)
    models = tuple(Model.seed(s) for s in sensors)
    theta = truth.to_vector(ParameterLayout(models))
    problem = Problem.build(pos, models, 45.0, 0.0, theta)
    typical = problem.layout.typical(theta)
    rep = analyze(problem, theta, typical)
    lin = np.where(problem.layout.linearization_mask(), problem.layout.neutral(), theta)
    _, s, Vt = np.linalg.svd(jacobian(problem, lin, np.diag(typical)), full_matrices=False)
    plain = Vt[s >= max(INFO_MIN, 1e-7 * s[0])].T
    assert rep.rank == plain.shape[1]
    cosines = np.linalg.svd(rep.basis.T @ plain, compute_uv=False)
    assert np.all(cosines > 1 - 1e-6)  # same subspace, to finite-difference precision
    assert set(rep.held_reasons) == {ROTATION_REASON}


def test_rank_not_counting_decides_how_few_positions_are_enough():
    truth = CoefficientSet.seed_truth()
    few = simulate_positions(truth, "random", 5, sensors=("gyro",), seed=1)
    res = calibrate(few, CalibrationOptions(sensor="gyro"))  # partial: Kz held at the prior
    assert any(
        "cannot fully separate gyro.scale.Kz (0 % seen) (rank 5 of 12)" in n for n in res.notes
    )
    assert res.status["gyro.scale"][2] == "held"
    eight = simulate_positions(truth, "random", 8, sensors=("gyro",), seed=1)
    res = calibrate(eight, CalibrationOptions(sensor="gyro"))  # 8 equations, rank 8
    assert res.observability.rank == 8 and res.observability.redundancy == 0
    assert any("exactly determined" in n for n in res.notes)
    assert any("all 8 invariant equations are taken" in n for n in res.notes)
    sd = res.uncertainty["gyro.scale"]
    err = res.coefficients.values["gyro.scale"] - truth.values["gyro.scale"]
    assert np.all(np.abs(err) < 4 * sd)


def test_memory_is_linear_in_the_positions():
    """3,000 accel positions: a full SVD's U alone would be 3000^2 doubles = 72 MB."""
    pos = simulate_positions(CoefficientSet.seed_truth(), "random", 3000, sensors=("accel",))
    tracemalloc.start()
    try:
        res = calibrate(pos, CalibrationOptions(sensor="accel"))
        res.to_json_dict()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert res.observability.rank == 12
    assert peak < 25e6, f"peak {peak / 1e6:.0f} MB"
