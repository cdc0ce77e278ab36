"""The swarm's Gauss-Newton model and its separable search (issue 38): the whitened phase taken
from the model's own Jacobian makes the model's Hessian the identity, so blocks of directions
are searched side by side (recal.solve.separable), and the cycles end once the model matches the
exact objective where the runs are. No timing here: benchmarks/bench_mcs_slews.py measures it."""

from __future__ import annotations

import numpy as np
import pytest

from recal.solve.calibrate import calibrate
from recal.solve.nafsa import NafsaConfig, nafsa
from recal.solve.options import CalibrationOptions
from recal.solve.phases import WHITENED_BLOCK, whitened_phase
from recal.solve.separable import block_layout, search_blocks
from recal.solve.surrogate import SurrogateProblem, data_noise


def test_blocks_cover_the_directions_with_the_least_padding():
    assert block_layout(24, 3) == (24, 8, 3) and block_layout(24, 3).pad == 0
    lay = block_layout(7, 3)
    assert (lay.blocks, lay.size, lay.pad) == (3, 3, 2)
    assert block_layout(2, 3) == (2, 1, 2) and block_layout(5, 6).pad == 0


@pytest.mark.parametrize("d", [7, 9])
def test_the_block_swarms_find_every_runs_minimum_of_a_separable_quadratic(d):
    """Per run c_r + g_r.x + x^T H x with H block diagonal (blocks of 3, padding when d = 7):
    the minimum -H^-1 g / 2 is found in every direction, and the reported objective is the full
    quadratic at the step."""
    rng = np.random.default_rng(5)
    R = 6
    H = np.zeros((d, d))
    for lo in range(0, d, 3):
        A = rng.normal(size=(min(3, d - lo),) * 2)
        H[lo : lo + 3, lo : lo + 3] = A @ A.T + np.eye(A.shape[0])
    g = rng.normal(size=(R, d))
    c = rng.normal(size=R)
    best = -0.5 * np.linalg.solve(H, g.T).T
    found = search_blocks(nafsa, NafsaConfig(iterations=60), rng, c, g, H, np.full(d, 3.0), 3)
    assert found.step.shape == (R, d)
    np.testing.assert_allclose(found.step, best, atol=1e-4)
    expect = c + np.einsum("rd,rd->r", found.step, g + found.step @ H)
    np.testing.assert_allclose(found.objective, expect, rtol=1e-12)
    assert np.all(np.diff(found.history, axis=1) <= 1e-12)  # best-so-far never worsens
    assert found.evaluations > 0


def test_whitened_for_its_own_model_the_hessian_is_the_identity(slew_lm):
    """The phase whitened with the model's Jacobian: H = I / (R - 1) to rounding, so no cross
    term between blocks is dropped; the model's objective is the exact one at its reference."""
    problem, theta = slew_lm.problem, slew_lm.theta
    typical = problem.layout.typical(theta)
    model = SurrogateProblem.at(problem, theta, typical)
    assert model.quadratic and model.linear == problem.invariant_names
    phase = whitened_phase(problem, theta, typical, slew_lm.observability,
                           jacobian_along=model.jacobian_along)  # fmt: skip
    assert phase.blocks == WHITENED_BLOCK
    _, _, H = model.phase_quadratic(theta[None], phase.transform)
    d = H.shape[0]
    np.testing.assert_allclose(H * problem.objective_dof, np.eye(d), atol=1e-9)
    np.testing.assert_allclose(model.objective(theta[None]), problem.objective(theta[None]),
                               rtol=1e-9)  # fmt: skip


def test_one_residual_evaluation_gives_the_perturbed_and_the_measured_objective(slew_lm):
    problem, theta = slew_lm.problem, slew_lm.theta
    typical = problem.layout.typical(theta)
    rng = np.random.default_rng(2)
    model = SurrogateProblem.at(problem, theta, typical, data_noise(problem, 4, rng))
    runs = np.arange(4)
    at = theta + 0.3 * typical * rng.normal(size=(4, theta.size)) * 1e-3
    own, measured = model.exact_objectives(at, runs)
    np.testing.assert_allclose(own, model.exact_objective(at, runs), rtol=1e-12)
    np.testing.assert_allclose(measured, problem.objective(at), rtol=1e-12)
    # one row of parameters for every run: the start of a batch
    own0, measured0 = model.exact_objectives(theta[None], runs)
    assert own0.shape == (4,) and np.ptp(measured0) == 0
    np.testing.assert_allclose(own0, model.exact_objective(np.repeat(theta[None], 4, 0), runs),
                               rtol=1e-12)  # fmt: skip


def test_the_cycles_end_once_the_model_matches_and_the_answer_is_lms(
    slew_session, slew_lm, slew_latitude
):
    """From the prior the first model is off where the runs land; the second, taken at their
    mean, matches the exact objective there, and the cycles end (the cap is 4)."""
    pos, slews = slew_session
    opt = CalibrationOptions(method="nafsa", mc_runs=40, seed=4, latitude_deg=slew_latitude,
                             slews=slews)  # fmt: skip
    res = calibrate(pos, opt)
    assert opt.cycles == 4 and res.mcs.cycles == 2
    est = slew_lm.observability.estimated
    sd = np.sqrt(np.diag(slew_lm.covariance_measurement))[est]
    z = np.abs(res.theta - slew_lm.theta)[est] / sd
    assert np.median(z) < 0.1 and np.all(z < 0.5)
    assert res.convergence["converged"] is True
    ratio = res.mcs.std[est] / sd  # each run on its own data: the spread is LM's sigma
    assert 0.75 < np.median(ratio) < 1.3
