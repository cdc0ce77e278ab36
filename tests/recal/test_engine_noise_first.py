"""Observability decided on real noise, noise sources named, refusals that name their cause,
one BLAS thread in the in-process swarm."""

import re

import numpy as np
import pytest

from recal.errors import RecalInputError
from recal.model.coefficients import CoefficientSet
from recal.model.positions import GYRO_SEM_COLUMNS, GYRO_STD_COLUMNS, Positions
from recal.sim.simulate import NoiseSpec, simulate_positions
from recal.solve.calibrate import calibrate
from recal.solve.mcs import run_mcs
from recal.solve.options import CalibrationOptions


def _without(pos: Positions, suffix: str) -> Positions:
    return Positions({k: v for k, v in pos.columns.items() if not k.endswith(suffix)}, pos.source)


def test_gyro_without_noise_columns_is_decided_on_the_estimated_noise():
    """20 random 300 s holds: the provisional sigma (0.01 deg/h, 6x the real noise) made Kx look
    unobservable ("rank 8 of 12"); the data pin it to ~100 ppm."""
    truth = CoefficientSet.seed_truth()
    full = simulate_positions(truth, "random", 20, 45.0, 0.0, 0, ("gyro",), NoiseSpec(window_s=300))
    res = calibrate(_without(full, "_std"), CalibrationOptions(sensor="gyro"))
    assert res.observability.rank == 9 and res.observability.noise_decided
    assert res.problem.sigma_source == {"gyro_norm": "residuals"}
    K, sd = res.coefficients.values["gyro.scale"], res.uncertainty["gyro.scale"]
    assert np.all(sd / K < 200e-6)
    assert np.all(np.abs(K - truth.values["gyro.scale"]) < 3 * sd)
    # the same decision and about the same sigma as with the noise columns
    ref = calibrate(full, CalibrationOptions(sensor="gyro"))
    assert np.all(
        (sd / ref.uncertainty["gyro.scale"] > 0.5) & (sd / ref.uncertainty["gyro.scale"] < 2)
    )
    assert any("no *_std or *_sem columns" in n for n in res.notes)


def test_heading_only_design_without_noise_columns_is_partial_on_the_estimated_noise():
    """Decided on the noise estimated from a fit, not on a guess: the vertical axis's scale
    cannot be told from its bias, so it is held (a partial calibration, docs/reference.md#cli)."""
    pos = simulate_positions(CoefficientSet.seed_truth(), "vessel", 40, sensors=("gyro",), seed=1)
    res = calibrate(_without(pos, "_std"), CalibrationOptions(sensor="gyro"))
    assert res.observability.noise_decided and res.observability.verdict == "insufficient"
    assert res.problem.sigma_source == {"gyro_norm": "residuals"}
    assert res.status["gyro.scale"][2] == "held"
    assert any(n.startswith("partial calibration: the positions cannot fully separate")
               for n in res.notes)  # fmt: skip


def test_noise_source_is_named_and_sem_columns_take_precedence():
    pos = simulate_positions(CoefficientSet.seed_truth(), "24", sensors=("gyro",), seed=3)
    std_only = calibrate(pos, CalibrationOptions(sensor="gyro"))
    doc = std_only.to_json_dict()
    assert doc["noise_source"] == {"gyro_norm": "std columns (white-noise assumption)"}
    assert doc["residuals"]["gyro_norm"]["noise_source"] == doc["noise_source"]["gyro_norm"]
    assert "white-noise assumption" in doc["uncertainty_kind"]
    # correlated noise: the window means are 3x noisier than std/sqrt(samples) says
    sem = dict(pos.columns)
    white = pos.std_of_mean("gyro")
    for i, name in enumerate(GYRO_SEM_COLUMNS):
        sem[name] = 3.0 * white[:, i]
    with_sem = calibrate(Positions(sem, "sem.csv"), CalibrationOptions(sensor="gyro"))
    doc = with_sem.to_json_dict()
    assert with_sem.problem.noise_known
    assert doc["noise_source"] == {"gyro_norm": "sem columns"}
    ratio = with_sem.uncertainty["gyro.scale"] / std_only.uncertainty["gyro.scale"]
    # (the white-noise sigma is widened by sqrt(chi2_red) when that exceeds 1)
    assert np.allclose(ratio, 3.0 / np.sqrt(max(1.0, std_only.chi2_red)), rtol=0.05)
    floor = doc["residuals"]["gyro_norm"]["noise_floor"]
    assert floor == pytest.approx(
        3 * std_only.to_json_dict()["residuals"]["gyro_norm"]["noise_floor"], rel=0.01
    )
    # sem columns alone (no std columns) count as known noise too
    bare = _without(Positions(sem, "sem.csv"), "_std")
    assert all(c not in bare.columns for c in GYRO_STD_COLUMNS)
    assert calibrate(bare, CalibrationOptions(sensor="gyro")).problem.noise_known


def _short_hold_gyro(window_s: float, seed: int = 7) -> Positions:
    noise = NoiseSpec(arw_deg_rt_h=0.05, window_s=window_s, slew_s=5.0, rate_hz=100.0)
    return simulate_positions(
        CoefficientSet.seed_truth(), "random", 24, 45.0, 0.0, seed, ("gyro",), noise
    )


def test_gyro_refusal_names_hold_length_and_noise_not_a_sensor_class():
    pos = _short_hold_gyro(1.2)
    with pytest.raises(RecalInputError) as exc:
        calibrate(pos, CalibrationOptions(sensor="gyro"))
    msg = str(exc.value)
    assert "MEMS" not in msg and "from 1.2 s holds" in msg
    assert "Earth rate (15.04107 deg/h) is not visible" in msg
    needed = float(re.search(r"holds of about ([0-9.e+]+) s", msg).group(1))
    contrast = float(re.search(r"by only ([0-9.e+]+)x", msg).group(1))
    assert needed == pytest.approx(1.2 * (50 / contrast) ** 2, rel=0.01)
    # with the prior's scale the noise reads in deg/h
    prior = CoefficientSet.seed_truth()
    with pytest.raises(
        RecalInputError, match=r"window-mean noise \([0-9.]+ deg/h from 1.2 s"
    ) as exc:
        calibrate(pos, CalibrationOptions(sensor="gyro", prior=prior))
    # following the advice works: holds long enough to pin the scale factors calibrate
    pinned = float(re.search(r"\(holds of about ([0-9.e+]+) s\)", str(exc.value)).group(1))
    res = calibrate(_short_hold_gyro(1.5 * pinned), CalibrationOptions(sensor="gyro"))
    assert res.observability.rank == 9
    assert np.all(res.uncertainty["gyro.scale"] / res.theta[:3] < 1e-3)


def test_in_process_swarm_runs_with_one_blas_thread():
    from threadpoolctl import threadpool_info, threadpool_limits

    def blas_threads() -> int:
        return max(i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas")

    pos = simulate_positions(CoefficientSet.seed_truth(), "24", sensors=("gyro",), seed=2)
    base = calibrate(pos, CalibrationOptions(sensor="gyro"))
    seen = []

    def phases(runs: np.ndarray, model) -> list:
        seen.append(blas_threads())
        return []

    # the suite runs on one BLAS thread (tests/conftest.py): give this process two, so that
    # the swarm's limit to one shows
    with threadpool_limits(2, user_api="blas"):
        before = blas_threads()
        run_mcs(base.problem, base.theta, phases, "nafsa", runs=3, cycles=1, workers=1)
        assert before == 2 and seen and set(seen) == {1}
        assert blas_threads() == before  # restored afterwards
