"""recal.detect.slew_groups: integration of downsampled increments, the simulator's slews, the joint fit."""

from __future__ import annotations

import math

import numpy as np
import pytest

from recal.detect.slew_collect import SlewCollector, SlewTracker, slews_from_reduced
from recal.detect.slew_data import Slews
from recal.detect.slew_gauge import in_accel_frame
from recal.detect.slew_groups import build_slews, compose_groups, group_increments, shift_reference
from recal.detect.slew_rotation import DEG_H_TO_RAD_S, integrate_samples, slew_rotations
from recal.model.coefficients import CoefficientSet
from recal.model.error_model import ParameterLayout
from recal.model.reference import OMEGA_IE_RAD_S
from recal.sim.session import session_positions, session_slews, simulate_session
from recal.sim.simulate import NoiseSpec
from recal.solve.calibrate import build_models, calibrate
from recal.solve.observability import COMMON_ROTATION_REASON
from recal.solve.options import CalibrationOptions
from recal.solve.problem import Problem

QUIET = NoiseSpec(arw_deg_rt_h=0.0, vrw_ug_rt_hz=0.0)


def _coning_slew(groups: int):
    """A 7 s slew about a wandering axis (coning), through a gyro with scale, bias and E."""
    dt, t = 0.01, np.arange(700) * 0.01
    w = np.column_stack([1.5 * np.sin(2 * t), 0.8 * np.cos(3 * t), 0.5 + 0.3 * np.sin(5 * t)])
    K, b = np.array([100.0, 120.0, 90.0]), np.array([3.0, -2.0, 1.0])
    A = np.eye(3) + np.array([[0, 1e-3, 2e-3], [-1e-3, 0, 3e-3], [5e-4, -2e-3, 0]])
    N = K * (w / DEG_H_TO_RAD_S @ A.T + b)
    ref = N[0] + 5.0
    slews = build_slews(
        [(0, 1, ref, N)], dt, np.array([0.0, 10]), np.array([1.0, 11]), groups=groups
    )
    q, rest = slew_rotations(slews, K[None, None], A[None], b[None, None])
    exact = integrate_samples(w, dt)
    err = 2 * min(np.linalg.norm(q[0, 0] - exact), np.linalg.norm(q[0, 0] + exact))
    return err, rest[0, 0], np.linalg.solve(A, ref / K - b) * DEG_H_TO_RAD_S


def test_downsampled_increments_keep_the_coning_correction():
    """64 increments reproduce the sample-by-sample rotation of a coning slew (2.8 rad) to
    2e-5 rad; the error falls as G^-4 (second-order composition inside each group is exact)."""
    errs = {g: _coning_slew(g)[0] for g in (16, 64, 256)}
    assert errs[64] < 2e-5 and errs[256] < 1e-7 and errs[16] > 100 * errs[64]
    _, rest, expected = _coning_slew(64)
    assert np.allclose(rest, expected, rtol=1e-12)  # the calibrated rest rate of window k


@pytest.fixture(scope="module")
def quiet_problem():
    truth = CoefficientSet.seed_truth()
    s = simulate_session(truth, "24", latitude_deg=45.0, seed=3, rate_hz=200, window_s=6,
                         slew_s=5, noise=QUIET)  # fmt: skip
    models = build_models(("gyro", "accel"), (), (), 25.0)
    theta = truth.to_vector(ParameterLayout(models))
    return s, models, theta


@pytest.mark.parametrize("earth", [True, False])
def test_simulated_slews_are_physically_consistent(quiet_problem, earth):
    """Noise-free session at the truth: with Earth's rotation taken out the slew residual is the
    integration error only (< 2e-6 rad at 200 Hz); left in, it is Omega cos(lat) T."""
    s, models, theta = quiet_problem
    slews = session_slews(s)
    p = Problem.build(session_positions(s), models, 45.0, 0.0, theta, slews=slews,
                      slew_earth_rate=earth)  # fmt: skip
    r = np.abs(p.raw_residuals(theta[None])["slew"][0])
    T = float(slews.duration_s[0])
    if earth:
        assert r.max() < 2e-6
    else:
        earth_turn = OMEGA_IE_RAD_S * math.cos(math.radians(45.0)) * T
        assert 0.3 * earth_turn < r.max() < 1.01 * earth_turn


def test_side_file_round_trip_and_mismatch(quiet_problem):
    s, _, _ = quiet_problem
    slews = session_slews(s)
    back = Slews.from_npz_bytes(slews.to_npz_bytes())
    for name in ("first", "second", "samples", "sums", "weighted", "cross", "reference"):
        assert np.array_equal(getattr(back, name), getattr(slews, name))
    pos = session_positions(s)
    assert back.mismatch(pos.columns["start_s"], pos.columns["end_s"]) is None
    assert back.mismatch(pos.columns["start_s"] + 1.0, pos.columns["end_s"]) is not None


def test_collector_drops_and_counts_a_slew_with_a_lost_frame(quiet_problem):
    """A lost frame, an invalid frame or a saturated sample in a slew: that slew is dropped and
    counted; the others are kept identical to those of the whole recording."""
    s, _, _ = quiet_problem

    class W:  # the Window fields the collector reads
        def __init__(self, k):
            self.start_index, self.end_index = int(s.hold_first[k]), int(s.hold_last[k])
            self.start_s, self.end_s = s.hold_start_s[k], s.hold_end_s[k]
            self.gyro = s.gyro_out[self.start_index : self.end_index + 1].mean(axis=0)

    windows = [W(k) for k in range(s.n_holds)]
    n = len(s)
    lost = np.zeros(n, dtype=np.int64)
    valid = np.ones(n, dtype=bool)
    lost[int(s.hold_last[2]) + 100] = 3  # in slew 2
    valid[int(s.hold_last[5]) + 10] = False  # in slew 5
    col = SlewCollector(windows, 1 / s.rate_hz)
    longest = int((s.hold_first[1:] - s.hold_last[:-1]).max())
    for a in range(0, n, 7001):  # chunked like a stream
        sl = slice(a, a + 7001)
        col.feed(s.time_s[sl], s.gyro_out[sl], valid=valid[sl], lost_before=lost[sl])
        assert col.held_frames <= longest  # raw frames of one slew at most, never the recording
    got = col.result()
    assert got.dropped == {"lost_frames": 1, "invalid_frames": 1, "saturated": 0, "too_long": 0}
    assert len(got) == s.n_holds - 3 and 2 not in got.first and 5 not in got.first
    whole = session_slews(s)
    keep = np.isin(whole.first, got.first)
    assert np.allclose(got.sums, whole.sums[keep], rtol=1e-12, atol=1e-12)
    limits = SlewCollector(windows, 1 / s.rate_hz, gyro_limits=(-1e12, 1e3))
    limits.feed(s.time_s, s.gyro_out)
    assert limits.result().dropped["saturated"] == s.n_holds - 1  # every slew turns past 1e3
    # hours of motion between two windows is no slew: never collected, counted
    short = SlewCollector(windows, 1 / s.rate_hz, max_slew_s=0.5 * longest / s.rate_hz)
    short.feed(s.time_s, s.gyro_out)
    assert short.held_frames == 0 and short.result().dropped["too_long"] == s.n_holds - 1


def _fit(seed: int, slews: bool, noise: NoiseSpec | None = None, truth=None):
    truth = truth or CoefficientSet.seed_truth()
    s = simulate_session(truth, "24", latitude_deg=45.0, seed=seed, rate_hz=200, window_s=20,
                         slew_s=5, noise=noise)  # fmt: skip
    opt = CalibrationOptions(latitude_deg=45.0, slews=session_slews(s) if slews else None)
    r = calibrate(session_positions(s), opt)
    tv = truth.to_vector(r.layout)
    if slews:
        tv = in_accel_frame(tv, r.layout)
    sd = np.concatenate([r.uncertainty[n] for n in r.layout.term_slices()])
    status = np.concatenate([r.status[n] for n in r.layout.term_slices()])
    return r, r.theta - tv, sd, status


def test_slews_estimate_all_twelve_gyro_coefficients_within_three_sigma():
    """20 seeds: with slews none of the 12 gyro coefficients is held, every error (gyro and
    accel, in the accelerometer-frame gauge) is within 3 sigma, and the antisymmetric gyro
    misalignment errors shrink against the fit without slews."""
    anti_with, anti_without, worst = [], [], 0.0
    for seed in range(20):
        r, err, sd, status = _fit(seed, slews=True)
        gyro = np.array([n.startswith("gyro.") for n in r.layout.names])
        assert (status[gyro] == "estimated").all()
        assert np.all(r.observability.share[gyro] > 0.99)
        est = status == "estimated"
        worst = max(worst, float(np.max(np.abs(err[est] / sd[est]))))
        names = r.layout.names
        ix = {n.rsplit(".", 1)[1]: i for i, n in enumerate(names) if "gyro.misalignment" in n}
        anti = [
            err[ix[a]] - err[ix[b]] for a, b in (("Exz", "Eyz"), ("Exy", "Ezy"), ("Eyx", "Ezx"))
        ]
        anti_with.append(anti)
        if seed < 5:
            r0, err0, _, _ = _fit(seed, slews=False)
            anti_without.append([err0[ix[a]] - err0[ix[b]] for a, b in (("Exz", "Eyz"),
                                 ("Exy", "Ezy"), ("Eyx", "Ezx"))])  # fmt: skip
        reasons = set(r.observability.held_reasons)
        assert reasons == {COMMON_ROTATION_REASON}
    assert worst < 3.0 * 1.3  # 27 x 20 normal z-scores: the largest is ~3.5 by chance
    rms_with = float(np.sqrt(np.mean(np.square(anti_with))))
    rms_without = float(np.sqrt(np.mean(np.square(anti_without))))
    assert rms_with < rms_without / 10


def test_a_gyro_blind_to_earth_rate_is_calibrated_from_the_slews():
    """A MEMS-like gyro (noise 1 deg/sqrt(h): window means 30x noisier than a FOG's) cannot see
    Earth rate; with slews its scale and misalignment are estimated anyway, within 3 sigma."""
    noisy = NoiseSpec(arw_deg_rt_h=1.0, vrw_ug_rt_hz=50.0)
    r, err, sd, status = _fit(1, slews=True, noise=noisy)
    assert r.problem.sensors == ("gyro", "accel") and not r.problem.slew_earth_rate
    assert any("still windows and 23 slews in one fit" in n for n in r.notes)
    gyro = np.array([n.startswith("gyro.") for n in r.layout.names])
    assert (status[gyro] == "estimated").all()
    scale = [i for i, n in enumerate(r.layout.names) if n.startswith("gyro.scale")]
    assert np.all(sd[scale] / r.theta[scale] < 2e-3)
    assert np.all(np.abs(err[gyro] / sd[gyro]) < 3.5)
    r0 = calibrate(session_positions(simulate_session(CoefficientSet.seed_truth(), "24",
                   latitude_deg=45.0, seed=1, rate_hz=200, window_s=20, slew_s=5, noise=noisy)),
                   CalibrationOptions(latitude_deg=45.0))  # fmt: skip
    assert r0.problem.sensors == ("accel",)  # without slews it is skipped, as before


def test_group_sums_compose_and_shift_exactly():
    """Joining runs of groups and changing the reference reproduce the direct sums."""
    rng = np.random.default_rng(5)
    g = rng.normal(size=(1000, 3)) * 50 + 7
    ref = np.array([3.0, -1.0, 2.0])
    small = group_increments(g, 0.01, np.zeros(3), 125)  # blocks of 8
    starts = (np.arange(16) * 125) // 16
    joined = shift_reference(*compose_groups(*small, starts), ref * 0.01)
    # the same group boundaries, computed directly from the samples
    counts = joined[0]
    direct = [group_increments(c, 0.01, ref, 1) for c in np.split(g, np.cumsum(counts)[:-1])]
    for k in range(1, 4):
        want = np.concatenate([d[k] for d in direct])
        assert np.allclose(joined[k], want, rtol=1e-10, atol=1e-9)


class _Win:
    """The Window fields the collector and the tracker read, from a simulated session."""

    def __init__(self, s, k):
        self.start_index, self.end_index = int(s.hold_first[k]), int(s.hold_last[k])
        self.start_s, self.end_s = s.hold_start_s[k], s.hold_end_s[k]
        self.gyro = s.gyro_out[self.start_index : self.end_index + 1].mean(axis=0)


def _track(s, windows, chunk, valid=None, lost=None, **kw):
    """Feed a session to a SlewTracker in chunks, closing each window one chunk after it ends
    (a live detector closes a window only after its end)."""
    tr = SlewTracker(1 / s.rate_hz, **kw)
    out, pending = [], list(windows)
    peak = 0
    for a in range(0, len(s), chunk):
        sl = slice(a, a + chunk)
        tr.feed(s.gyro_out[sl], None if valid is None else valid[sl],
                None if lost is None else lost[sl])  # fmt: skip
        while pending and pending[0].end_index < a:  # closed a chunk late
            r = tr.window(pending.pop(0))
            if r is not None:
                out.append(r)
        peak = max(peak, tr.held_bytes)
    for w in pending:
        r = tr.window(w)
        if r is not None:
            out.append(r)
    return out, peak


def test_live_tracker_matches_the_collector_with_bounded_memory(quiet_problem):
    """The daemon's tracker gives the slews of the offline collector (the integrated rotations
    agree to the Earth rotation over the <= 7 extra static frames), holds a bounded number of
    bytes, and drops a slew with a lost frame."""
    s, models, theta = quiet_problem
    windows = [_Win(s, k) for k in range(s.n_holds)]
    lost = np.zeros(len(s), dtype=np.int64)
    lost[int(s.hold_last[2]) + 100] = 1  # in slew 2
    reduced, peak = _track(s, windows, 3000, lost=lost, lag_s=30.0, max_slew_s=60.0)
    start = np.array([w.start_s for w in windows])
    end = np.array([w.end_s for w in windows])
    rows = {id(w): k for k, w in enumerate(windows)}
    live = slews_from_reduced([(rows[id(r.first)], rows[id(r.second)], r) for r in reduced],
                              1 / s.rate_hz, start, end)  # fmt: skip
    assert live.dropped["lost_frames"] == 1 and len(live) == s.n_holds - 2
    assert 2 not in live.first
    # (30 s lag + 60 s slew) of blocks of 8 frames at 200 Hz, 10 float64 each, + a little
    assert peak < (90 * 200 / 8 + 10) * 100
    whole = session_slews(s)
    keep = np.isin(whole.first, live.first)
    gyro = models[0]
    sl = slice(0, gyro.size)
    gain, A, offset, _ = gyro._parts(theta[None, sl], {})
    q_live, _ = slew_rotations(live, gain, A, offset)
    q_all, _ = slew_rotations(whole.subset(keep), gain, A, offset)
    dq = np.minimum(
        np.linalg.norm(q_live - q_all, axis=-1), np.linalg.norm(q_live + q_all, axis=-1)
    )
    earth_8_frames = OMEGA_IE_RAD_S * 16 / s.rate_hz
    assert dq.max() < earth_8_frames + 1e-9
