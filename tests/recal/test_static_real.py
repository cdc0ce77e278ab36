"""recal.detect.static_detector on real recordings (issue 7): thresholds with no flag, short holds, lost frames,
correlated noise. Sample-level sessions from recal.sim.session, KVH bytes from service.capture_sim."""

from __future__ import annotations

import numpy as np
import pytest

from drivers import DecoderConfig, decode_bulk
from drivers.xsens_text import load_xsens_pair
from recal.detect.floor import NoiseFloor, NoiseFloorEstimator, estimate_noise_floor
from recal.detect.noise import pooled_standard_errors
from recal.detect.static_config import DetectorConfig
from recal.detect.static_detector import StaticDetector, detect_static
from recal.detect.windows import windows_to_columns
from recal.errors import RecalInputError
from recal.model.positions import ACCEL_SEM_COLUMNS, GYRO_SEM_COLUMNS, Positions
from recal.sim.session import Session, gauss_markov, simulate_session
from recal.sim.simulate import NoiseSpec
from recal.solve.calibrate import calibrate
from recal.solve.options import CalibrationOptions
from service.capture_sim import Damage, kvh_like_truth, session_to_kvh

FOG = NoiseSpec(arw_deg_rt_h=5e-4, vrw_ug_rt_hz=20.0)


def short_holds(hold_s: float, slew_s: float = 2.0, n: int = 16, seed: int = 2) -> Session:
    """A 1 kHz session of short holds: a third of it still when hold_s = 1 and slew_s = 2."""
    return simulate_session(
        kvh_like_truth(seed),
        "random",
        n,
        seed=seed,
        rate_hz=1000.0,
        window_s=hold_s,
        slew_s=slew_s,
        noise=FOG,
    )


def hold_of(session: Session, first_frames: np.ndarray) -> np.ndarray:
    return np.searchsorted(session.hold_first, first_frames, side="right") - 1


def assert_one_window_per_hold(session: Session, windows, offset: int = 0, skip: int = 0):
    first = np.array([w.start_index for w in windows]) + offset
    last = np.array([w.end_index for w in windows]) + offset
    holds = hold_of(session, first)
    np.testing.assert_array_equal(holds, np.arange(skip, session.n_holds))
    assert all(session.static[a : b + 1].all() for a, b in zip(first, last, strict=True))


# ---- the noise floor, with no flag ---------------------------------------------------------
@pytest.fixture(scope="module")
def xsens(shared_data):
    d = load_xsens_pair(
        shared_data / "xsens_static_poses_acc.txt", shared_data / "xsens_static_poses_gyro.txt"
    )
    return d["time_s"], d["gyro_counts"], d["accel_counts"]


def test_xsens_flag_free_finds_the_38_poses(xsens):
    res = detect_static(*xsens)  # no threshold, no still period
    assert len(res.windows) == 38
    learned = detect_static(*xsens, config=DetectorConfig(init_still_s=50.0))
    # The same holds, to a frame or two (the thresholds differ by a few %).
    for w, ref in zip(res.windows, learned.windows, strict=True):
        assert abs(w.start_index - ref.start_index) <= 5 and abs(w.end_index - ref.end_index) <= 5
    # The floor learned from the quiet stretches matches the one of the 50 s still period.
    rep = res.report
    assert rep.accel_threshold == pytest.approx(learned.report.accel_threshold, rel=0.1)
    assert rep.gyro_threshold == pytest.approx(learned.report.gyro_threshold, rel=0.1)
    assert "quietest" in rep.threshold_source and rep.thresholds_learned
    assert any(rep.threshold_source in line for line in rep.summary_lines())
    assert "initial 50 s still period" in learned.report.threshold_source
    # The windows' own moving-variance trace: what the daemon refines its floor from.
    floor = estimate_noise_floor(*xsens)
    mvar = np.array([w.accel_mvar for w in res.windows])
    assert (mvar <= rep.accel_threshold).all()
    assert np.median(mvar) == pytest.approx(floor.accel, rel=0.3)


def test_xsens_per_triad_stillness_keeps_the_38_windows(xsens):
    """A unit on a table: per-triad stillness adds no window, drops none, and the report
    counts the 38 poses as seen and used with nothing rejected."""
    floor = estimate_noise_floor(*xsens)
    res = detect_static(*xsens, config=DetectorConfig(noise_floor=floor))
    old = detect_static(*xsens, config=DetectorConfig(noise_floor=floor, accel_only_windows=False))
    assert [(w.start_index, w.end_index) for w in res.windows] == [
        (w.start_index, w.end_index) for w in old.windows
    ]
    assert len(res.windows) == 38 and all(w.gyro_still for w in res.windows)
    rep = res.report
    assert rep.still_stretches == rep.still_stretches_used == 38
    assert sum(rep.rejected.values()) == 0 and rep.rejected_stretches == []
    lines = rep.summary_lines()
    assert "windows: 38 kept; rejected:" in lines[2]
    assert (
        lines[3]
        == "poses: 38 still stretches of the accelerometer seen, 38 used, 0 without any window"
    )
    assert len(lines) == 4  # no rejected stretch to list


def test_noise_floor_incremental_equals_bulk(xsens):
    t, g, a = xsens
    bulk = estimate_noise_floor(t, g, a)
    est = NoiseFloorEstimator()
    rng = np.random.default_rng(1)
    lo = 0
    while lo < t.shape[0]:
        hi = lo + int(rng.integers(1, 3000))
        est.feed(t[lo:hi], g[lo:hi], a[lo:hi])
        lo = hi
    assert est.result() == bulk
    assert bulk.window_samples == 101 and bulk.thresholds(5.0) == (5 * bulk.accel, 5 * bulk.gyro)
    with pytest.raises(RecalInputError, match="too little data"):
        estimate_noise_floor(t[:500], g[:500], a[:500])


def test_a_third_still_starting_in_motion_1s_holds_at_1khz():
    s = short_holds(1.0)
    cut = int(s.hold_last[0]) + 1000  # start in the middle of the first slew: nothing still
    t, g, a = s.time_s[cut:], s.gyro_out[cut:], s.accel_out[cut:]
    res = detect_static(t, g, a)
    assert_one_window_per_hold(s, res.windows, offset=cut, skip=1)
    assert all(w.duration_s > 0.7 for w in res.windows)
    # The same through the incremental detector, given the floor of a first pass.
    floor = estimate_noise_floor(t, g, a)
    det = StaticDetector(DetectorConfig(noise_floor=floor))
    got = []
    for lo in range(0, t.shape[0], 777):
        got += det.feed(t[lo : lo + 777], g[lo : lo + 777], a[lo : lo + 777])
    got += det.flush()
    assert [(w.start_index, w.end_index) for w in got] == [
        (w.start_index, w.end_index) for w in res.windows
    ]


def test_quantised_still_data_do_not_give_a_zero_floor():
    # Raw counts with noise well below one count: most still blocks read exactly 0.
    rng = np.random.default_rng(3)
    n = 6000
    t = np.arange(n) / 100.0
    a = np.rint(np.array([100.0, -20.0, 3000.0]) + 0.2 * rng.standard_normal((n, 3)))
    g = np.rint(np.array([5.0, 7.0, -2.0]) + 0.2 * rng.standard_normal((n, 3)))
    a[3000:3300] += np.rint(np.linspace(0, 400, 300))[:, None]  # one tilt in the middle
    floor = estimate_noise_floor(t, g, a)
    assert floor.accel >= 3 / 12 and floor.gyro >= 3 / 12  # step^2 / 12 per axis
    res = detect_static(t, g, a)
    assert len(res.windows) == 2 and sum(w.samples for w in res.windows) > 5000


def test_detector_without_any_threshold_source_is_an_input_error():
    with pytest.raises(RecalInputError, match="noise floor"):
        StaticDetector(DetectorConfig())
    floor = NoiseFloor(accel=1e-6, gyro=1.0, window_samples=101, source="stored")
    det = StaticDetector(DetectorConfig(noise_floor=floor, accel_threshold=2e-6))
    assert det.report.threshold_source == "stored (accel given)"


# ---- short holds ---------------------------------------------------------------------------
def test_too_short_stretches_are_reported_with_the_option_that_keeps_them():
    s = short_holds(0.6, n=8)
    res = detect_static(s.time_s, s.gyro_out, s.accel_out)
    rep = res.report
    assert len(res.windows) == 0 and rep.short_stretches >= s.n_holds
    line = rep.summary_lines()[-1]
    assert "too short" in line and "min_duration_s" in line
    shortest = rep.accepting_min_duration_s()
    cfg = DetectorConfig(noise_floor=estimate_noise_floor(s.time_s, s.gyro_out, s.accel_out))
    res = detect_static(
        s.time_s,
        s.gyro_out,
        s.accel_out,
        config=DetectorConfig(**{**cfg.__dict__, "min_duration_s": shortest}),
    )
    assert len(res.windows) >= 1


# ---- lost frames ---------------------------------------------------------------------------
def test_damaged_capture_gives_one_window_per_hold():
    s = simulate_session(
        kvh_like_truth(4), "24", seed=4, rate_hz=1000.0, window_s=3.0, slew_s=1.5, noise=FOG
    )
    n_damaged = len(s) // 1000  # 0.1 % of the frames: half dropped, half with a flipped bit
    data, info = session_to_kvh(
        s, "kvh-a", damage=Damage(bit_flips=n_damaged // 2, drops=n_damaged // 2), rng=4
    )
    b, _ = decode_bulk(data, "kvh-a", DecoderConfig(rate_hz=1000.0))
    args = (b.time_s, b.gyro_dph, b.accel_g, b.temperature_c, b.valid, b.lost_before)
    res = detect_static(*args)
    frame = np.rint(b.time_s * 1000.0).astype(np.int64)  # session frame of each decoded frame
    first = frame[[w.start_index for w in res.windows]]
    np.testing.assert_array_equal(hold_of(s, first), np.arange(s.n_holds))
    cols = windows_to_columns(res.windows)
    assert cols["frames_lost"].sum() > 0  # bridged, and counted
    for w in res.windows:  # the means are those of the frames that arrived
        sel = slice(w.start_index, w.end_index + 1)
        np.testing.assert_allclose(w.accel, b.accel_g[sel].mean(axis=0), rtol=0, atol=1e-9)
    # A longer gap still splits, and splitting at every hole was the old behaviour.
    split = detect_static(*args, config=DetectorConfig(max_gap_frames=0))
    assert len(split.windows) > s.n_holds


# ---- correlated noise: the standard error of a window mean ---------------------------------
def test_gauss_markov_bias_has_its_variance_and_correlation_time():
    x = gauss_markov(np.random.default_rng(0), 400_000, 2.0, 0.5, 100.0)[:, 0]
    assert x.std() == pytest.approx(2.0, rel=0.1)
    lag = 50  # one correlation time
    rho = np.corrcoef(x[:-lag], x[lag:])[0, 1]
    assert rho == pytest.approx(np.exp(-1.0), abs=0.05)
    # Off by default: the white-noise session is unchanged.
    base = dict(design="random", n_positions=3, seed=1, rate_hz=100.0, window_s=2, slew_s=1)
    plain = simulate_session(kvh_like_truth(1), **base)
    off = simulate_session(kvh_like_truth(1), **base, noise=NoiseSpec(gm_tau_s=5.0))
    np.testing.assert_array_equal(plain.accel_out, off.accel_out)


def chi2_red(cols: dict[str, np.ndarray], use_sem: bool) -> float:
    if not use_sem:
        cols = {k: v for k, v in cols.items() if not k.endswith("_sem")}
    opts = CalibrationOptions(sensor="both", latitude_deg=45.0)
    return calibrate(Positions.from_columns(cols), opts).chi2_red


@pytest.mark.parametrize("gm", [True, False], ids=["gauss-markov", "white"])
def test_window_sem_sees_correlated_noise(gm):
    # 40 s holds, a Gauss-Markov bias of 20 s correlation time dominating the mean's error.
    gm_noise = {"gm_accel_ug": 33.0, "gm_gyro_dph": 0.01, "gm_tau_s": 20.0} if gm else {}
    noise = NoiseSpec(arw_deg_rt_h=1e-4, vrw_ug_rt_hz=20.0, **gm_noise)
    s = simulate_session(
        kvh_like_truth(1), "24", seed=1, rate_hz=200.0, window_s=40, slew_s=5.0, noise=noise
    )
    ws = detect_static(s.time_s, s.gyro_out, s.accel_out).windows
    assert len(ws) == 24
    cols = windows_to_columns(ws)
    sem = np.column_stack([cols[c] for c in GYRO_SEM_COLUMNS + ACCEL_SEM_COLUMNS])
    white = np.column_stack([cols[f"{c[:-4]}_std"] for c in GYRO_SEM_COLUMNS + ACCEL_SEM_COLUMNS])
    white = white / np.sqrt(cols["samples"])[:, None]
    before, after = chi2_red(cols, use_sem=False), chi2_red(cols, use_sem=True)
    if gm:
        assert before > 20 and 0.3 < after < 2.0
        assert (sem > 3 * white).all()
    else:
        assert after == pytest.approx(before, rel=0.1) and after < 2.0
        np.testing.assert_allclose(sem, white, rtol=0.15)
    # Pooling gives the columns; each window also carries its own estimate.
    g, a = pooled_standard_errors(ws)
    np.testing.assert_array_equal(np.column_stack((g, a)), sem)
    own = np.array([np.concatenate((w.gyro_sem, w.accel_sem)) for w in ws])
    assert np.isfinite(own).all() and (own > 0).all()
