"""Per-triad stillness (issue 18 item 5) on hand-held MEMS recordings (recal.sim.session.
simulate_handheld): poses still enough for the accelerometer while the gyro shows tremor."""

from __future__ import annotations

import numpy as np
import pytest

from recal.detect import static_accel_only
from recal.detect.floor import estimate_noise_floor
from recal.detect.noise import pooled_standard_errors
from recal.detect.static_config import DetectorConfig
from recal.detect.static_detector import StaticDetector, detect_static
from recal.detect.windows import windows_to_columns
from recal.errors import RecalInputError
from recal.model.error_model import Model
from recal.model.positions import Positions
from recal.sim.session import simulate_handheld
from recal.solve.problem import Problem


def windows_per_hold(session, windows) -> np.ndarray:
    """How many windows lie inside each hold (a window over a slew belongs to none)."""
    start = np.array([w.start_index for w in windows])
    end = np.array([w.end_index for w in windows])
    inside = (start[None] >= session.hold_first[:, None]) & (
        end[None] <= session.hold_last[:, None]
    )
    assert inside.any(axis=0).all(), "a window reaches into a slew"
    return inside.sum(axis=1)


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4, 5])
def test_every_handheld_pose_gives_an_accelerometer_window(seed):
    s = simulate_handheld(seed=seed)
    res = detect_static(s.time_s, s.gyro_out, s.accel_out)
    assert (windows_per_hold(s, res.windows) >= 1).all()
    rep = res.report
    assert rep.still_stretches == rep.still_stretches_used == s.n_holds
    only = [w for w in res.windows if not w.gyro_still]
    assert rep.accel_only_windows == len(only) == rep.rejected["gyro_not_still"]
    # each is listed, with its span, as rejected for the gyro
    listed = {(a, b) for a, b, why in rep.rejected_stretches if why == "gyro_not_still"}
    assert listed == {(w.start_s, w.end_s) for w in only}


def test_without_per_triad_stillness_the_tremor_poses_are_dropped_silently():
    """The issue's symptom, kept as the reference: 2 of 10 poses and no rejection at all."""
    s = simulate_handheld(seed=0)
    floor = estimate_noise_floor(s.time_s, s.gyro_out, s.accel_out)
    old = detect_static(s.time_s, s.gyro_out, s.accel_out,
                        config=DetectorConfig(noise_floor=floor, accel_only_windows=False))  # fmt: skip
    assert len(old.windows) == 2 and sum(old.report.rejected.values()) == 0
    new = detect_static(s.time_s, s.gyro_out, s.accel_out, config=DetectorConfig(noise_floor=floor))
    assert len(new.windows) == 10
    # the both-triad windows are the same; the other 8 poses are kept for the accelerometer
    both = [w for w in new.windows if w.gyro_still]
    assert [(w.start_index, w.end_index) for w in both] == [
        (w.start_index, w.end_index) for w in old.windows
    ]
    lines = new.report.summary_lines()
    assert any("2 with both triads still, 8 for the accelerometer only" in x for x in lines)
    assert any("10 still stretches of the accelerometer seen, 10 used" in x for x in lines)
    why = [x for x in lines if "gyro not still (used for the accelerometer only)" in x]
    assert len(why) == 8


@pytest.mark.parametrize("sizes", [(1, 7, 64), (997,), (4096, 3)], ids=["tiny", "prime", "mixed"])
def test_handheld_detection_is_chunk_independent(sizes):
    s = simulate_handheld(seed=4)  # both kinds of windows and absorbed tremor fragments
    cfg = DetectorConfig(noise_floor=estimate_noise_floor(s.time_s, s.gyro_out, s.accel_out))
    ref = detect_static(s.time_s, s.gyro_out, s.accel_out, config=cfg)
    det = StaticDetector(cfg)
    got, lo, k = [], 0, 0
    while lo < len(s):
        hi = lo + sizes[k % len(sizes)]
        got += det.feed(s.time_s[lo:hi], s.gyro_out[lo:hi], s.accel_out[lo:hi])
        lo, k = hi, k + 1
    got += det.flush()
    assert [(w.start_index, w.end_index, w.gyro_still) for w in got] == [
        (w.start_index, w.end_index, w.gyro_still) for w in ref.windows
    ]
    for w, r in zip(got, ref.windows, strict=True):
        np.testing.assert_allclose(w.accel, r.accel, rtol=1e-12)
    assert det.report.rejected == ref.report.rejected
    assert sorted(det.report.rejected_stretches) == sorted(ref.report.rejected_stretches)
    assert det.report.still_stretches == ref.report.still_stretches


def test_a_short_pose_with_moving_edges_is_not_taken_for_tremor(monkeypatch):
    """2.5 s holds without tremor: the accelerometer is quiet longer than the gyro (it cannot
    see the slow start of a turn), but the gyro is still through most of it: too short, not
    tremor, so no accelerometer-only window (whose slews would miss the turns' edges)."""
    s = simulate_handheld(seed=0, n_poses=6, spec=_spec(hold_s=(2.5, 2.5), tremor_deg_s=(0, 0)))
    res = detect_static(s.time_s, s.gyro_out, s.accel_out)
    assert res.report.accel_only_windows == 0
    assert res.report.rejected["too_short"] == 6
    monkeypatch.setattr(
        static_accel_only, "GYRO_QUIET_SHARE", 1.01
    )  # without the rule: one slips in
    assert detect_static(s.time_s, s.gyro_out, s.accel_out).report.accel_only_windows == 1


def _spec(**kw):
    from dataclasses import replace

    from recal.sim.session import HandheldSpec

    return replace(HandheldSpec(), **kw)


def test_accelerometer_only_rows_are_left_out_of_the_gyro_invariants():
    s = simulate_handheld(seed=0)
    res = detect_static(s.time_s, s.gyro_out, s.accel_out)
    cols = windows_to_columns(res.windows)
    assert cols["gyro_still"].tolist() == [float(w.gyro_still) for w in res.windows]
    pos = Positions.from_columns(cols, source="handheld")
    prob = Problem.build(pos, (Model.seed("gyro"), Model.seed("accel")), 45.0)
    still = np.flatnonzero(cols["gyro_still"] == 1)
    assert prob.n_of("accel_norm") == 10
    assert prob.n_of("gyro_norm") == prob.n_of("dot") == still.size == 2
    np.testing.assert_array_equal(prob.rows_of("gyro_norm"), still)
    theta = prob.layout.neutral()
    raw = prob.raw_residuals(theta[None])
    assert raw["gyro_norm"].shape == (1, 2) and raw["accel_norm"].shape == (1, 10)
    assert prob.residuals(theta[None]).shape == (1, prob.n_residuals) == (1, 14)
    # the gyro's standard errors are pooled apart: tremor is not the gyro's noise
    own = pooled_standard_errors([res.windows[i] for i in still])[0]
    np.testing.assert_allclose(pos.std_of_mean("gyro")[still], own)
    mixed = pooled_standard_errors(res.windows)[0][still]
    assert not np.allclose(mixed, own)


def test_gyro_alone_needs_a_still_gyro_somewhere():
    s = simulate_handheld(seed=0)
    cols = windows_to_columns(detect_static(s.time_s, s.gyro_out, s.accel_out).windows)
    cols["gyro_still"][:] = 0.0
    pos = Positions.from_columns(cols, source="handheld.csv")
    with pytest.raises(RecalInputError, match="gyro was still in no window"):
        Problem.build(pos, (Model.seed("gyro"),), 45.0)
