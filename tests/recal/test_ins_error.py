"""Linear psi-angle error model (recal.nav.ins_error): what alignment hides, agreement with the
navigation, orientation dependence, uncertainty propagation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from recal.model.coefficients import CoefficientSet
from recal.nav.alignment import align_static
from recal.nav.ins_impact import describe_change
from recal.nav.ins_static import predict_static_error, schuler_amplitude_m
from recal.nav.ins_uncertainty import predict_from_uncertainty
from recal.nav.navigation import correct_outputs, decimate, navigate, schuler_period_s
from recal.nav.trajectory import VoyageSpec, simulate_voyage
from recal.sim.simulate import NoiseSpec

LAT = 45.0
TRUTH = CoefficientSet.seed_truth()


def _with(name: str, delta) -> CoefficientSet:
    used = TRUTH.copy()
    used.values[name] = TRUTH.values[name] + np.asarray(delta, float)
    return used


def test_alignment_hides_east_accel_bias_and_east_gyro_bias():
    for used in (
        _with("accel.bias", [0.0, -2e-4, 0.0]),  # heading 0: body y is east
        _with("gyro.bias", [0.0, 0.01, 0.0]),
    ):
        hidden = predict_static_error(used, TRUTH, LAT, aligned=True)
        seen = predict_static_error(used, TRUTH, LAT, aligned=False)
        assert seen.max_m > 1000.0
        assert hidden.max_m < 0.01 * seen.max_m  # what is left: the truth's misalignments
    # The north accel bias: levelling removes its Schuler oscillation, but Earth rate turns
    # the tilt it left: a 24 h error of order R del / g (640 m per 100 ug) remains.
    used = _with("accel.bias", [1e-4, 0.0, 0.0])
    aligned = predict_static_error(used, TRUTH, LAT, aligned=True)
    free = predict_static_error(used, TRUTH, LAT, aligned=False)
    assert schuler_amplitude_m(aligned.time_s, aligned.north_m, LAT) < 0.05 * schuler_amplitude_m(
        free.time_s, free.north_m, LAT
    )
    assert 300.0 < aligned.max_m < 2000.0
    # ... and not the gyro error along Earth's axis: north and down components remain
    north = predict_static_error(_with("gyro.bias", [0.01, 0.0, 0.0]), TRUTH, LAT)
    assert north.final_nmi > 1.0


def test_north_gyro_bias_after_alignment_matches_navigation():
    used = _with("gyro.bias", [0.01, 0.0, 0.0])
    v = simulate_voyage(TRUTH, VoyageSpec.static(2.1 * 3600), LAT, 0.0, 0.0, 10.0, NoiseSpec(0, 0))
    s = v.session
    w, f = correct_outputs([used], decimate(s.time_s, s.gyro_out, s.accel_out, None, 10.0))
    al = align_static(f[:, :3000], w[:, :3000], LAT)
    nav = navigate(w[:, 3000:], f[:, 3000:], 0.1, LAT, 0.0, 0.0, al.C_bn)
    n, e = nav.north_east_error_m(math.radians(LAT), 0.0)
    pred = predict_static_error(used, TRUTH, LAT, hours=2.0)
    nav_h = np.hypot(n[0], e[0])[::60][: pred.time_s.size]
    assert nav_h[-1] == pytest.approx(pred.final_m, rel=0.1)
    assert np.abs(nav_h - pred.horizontal_m).max() < 0.1 * pred.max_m


def test_the_error_depends_on_the_imu_orientation():
    """A scale error of the gyro z axis: level, z senses Earth rate's vertical part; on its
    side with z pointing north it senses the horizontal part."""
    used = _with("gyro.scale", TRUTH.values["gyro.scale"] * np.array([0, 0, 100e-6]))
    # at 30 deg the vertical Earth rate is half the horizontal one (at 45 they would be equal)
    level = predict_static_error(used, TRUTH, 30.0, attitude_rpy_deg=(0, 0, 0))
    z_north = predict_static_error(used, TRUTH, 30.0, attitude_rpy_deg=(0, -90, 0))
    assert abs(level.eps_ned_deg_h[2]) > 1e-4 and abs(level.eps_ned_deg_h[0]) < 1e-6
    assert abs(z_north.eps_ned_deg_h[0]) > 1e-4
    assert z_north.max_m > 1.3 * level.max_m


def test_uncertainty_from_sigmas_doc_and_covariance_agree_and_scale_linearly():
    sig = {"gyro.bias": np.full(3, 0.0015), "gyro.scale": np.zeros(3)}
    a = predict_from_uncertainty(CoefficientSet(sig), TRUTH, LAT, hours=6)
    doc = {"uncertainty": {"gyro": {"bias": [0.0015] * 3, "scale": [None] * 3}}}
    b = predict_from_uncertainty(doc, TRUTH, LAT, hours=6)
    cov = np.diag(np.r_[np.zeros(3), np.full(3, 0.0015**2), np.zeros(6)])
    c = predict_from_uncertainty(None, TRUTH, LAT, hours=6, covariance=cov)
    assert a.final_nmi > 0.05
    assert b.final_nmi == pytest.approx(a.final_nmi, rel=1e-9)
    assert c.final_nmi == pytest.approx(a.final_nmi, rel=1e-6)
    double = predict_from_uncertainty(
        CoefficientSet({"gyro.bias": np.full(3, 0.003)}), TRUTH, LAT, hours=6
    )
    assert double.final_nmi == pytest.approx(2 * a.final_nmi, rel=1e-6)


def test_describe_change_and_schuler():
    old = _with("gyro.bias", [0.01, -0.005, 0.008])
    text = describe_change(old, TRUTH, LAT, sigma_new={"gyro": {"bias": [0.001] * 3}})
    assert text.startswith("loading B instead of A changes the predicted 24 h static error")
    assert "nmi (1 sigma)" in text
    assert schuler_period_s(LAT) / 60 == pytest.approx(84.4, abs=0.3)
    p = predict_static_error(old, TRUTH, LAT, aligned=False)
    assert schuler_amplitude_m(p.time_s, p.north_m, LAT) > 10.0


def test_the_error_model_is_split_by_idea_and_its_names_stay() -> None:
    """Issue 38: the static model, the uncertainty's share and a version's impact live in
    modules of their own, each under 600 lines like ins_error.py itself; recal.nav.ins_error
    (docs/navigation.md) still gives every name it had, the same objects, and its star import
    the same list."""
    import importlib
    from pathlib import Path

    import recal.nav.ins_error as ins_error
    from recal.nav import ins_impact, ins_static, ins_uncertainty

    homes = (ins_static, ins_uncertainty, ins_impact)
    for name in ("PredictedError", "predict_static_error", "schuler_amplitude_m", "propagate",
                 "UncertaintyPrediction", "SEED_TERMS", "predict_from_uncertainty",
                 "NavigationImpact", "navigation_impact", "describe_change", "seed_covariance"):  # fmt: skip
        home = next(m for m in homes if hasattr(m, name))
        assert getattr(ins_error, name) is getattr(home, name), name
    assert len(ins_error.__all__) == 26
    assert all(hasattr(ins_error, name) for name in ins_error.__all__)
    for part in ("ins_error", "ins_static", "ins_uncertainty", "ins_impact"):
        module = importlib.import_module(f"recal.nav.{part}")
        assert len(Path(module.__file__).read_text().splitlines()) < 600, part
