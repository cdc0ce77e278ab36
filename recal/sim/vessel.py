"""A hull-fixed IMU on a vessel, sample by sample: berth holds that rock, steady turns, indexing.

This is what the product's first user sees (``shared/spec/vessel.md`` has the magnitudes): the
IMU is bolted to the hull, so new orientations come only from heading changes (the vessel swings
at its berth, turns in port, or sails) or from an indexing (rotation-modulation) mechanism
between the hull and the IMU. Even at berth the hull is never still: it rolls, pitches, heaves and
swings slowly in yaw.

A :class:`VesselSpec` is a list of :class:`Segment` s:

* ``hold``: the vessel keeps its heading (apart from the sea's yaw swing) for ``duration_s``;
* ``turn``: a steady heading change by ``heading_change_deg``: the turn rate rises over
  ``turn_ramp_s`` (raised cosine), stays constant, and falls again, so a moving-variance test sees
  only the ramps;
* ``index``: the indexing mechanism turns the IMU in the hull to ``mount_rpy_deg`` about the
  fixed axis of the relative rotation (raised-cosine angle profile, as the lab sessions of
  :mod:`recal.sim.session`);
* ``transit``: the ship sails on its heading at ``speed_kn`` (from a standstill and back to one,
  raised-cosine speed ramps of ``VesselSpec.speed_ramp_s``), a straight line over a spherical
  Earth of radius :data:`recal.detect.underway.EARTH_RADIUS_M`. Only here does the vessel move
  over the Earth: its inputs then carry the transport rate w_en^n = (v_E / R, -v_N / R,
  -v_E tan(lat) / R), Earth's rate and gravity at the latitude it has reached, and the Coriolis
  and Eotvos accelerations (2 w_ie^n + w_en^n) x v^n besides the speed ramps' own;
  :func:`ship_track` gives its position, speed, course and heading (what its GNSS and
  gyrocompass say).

The sea (:class:`SeaState`) moves the hull in every segment: roll, pitch and yaw swing, each a
narrow-band sum of sinusoids (``components`` periods spread by ``period_spread`` around the
nominal, random phases) whose peak amplitude is about the given one (RMS times sqrt 2), heave,
and the lever arm of the IMU from the hull's centre of rotation (tangential and centripetal
accelerations). Each segment scales the sea by its ``sea_scale`` (0 is a flat calm); the scale
changes smoothly over ``sea_ramp_s`` at a segment's start.

Frames: navigation frame NED, the vessel frame forward-right-down, the IMU body frame turned in
the hull by the mount (``C_nb = C_nv C_vb``). The inputs are exact kinematics at the middle of
each sample interval:

    w_ib^b = C_bn w_ie^n + C_bv w_nv^v(Euler rates) + w_vb^b(indexing)       (deg/h)
    f^b    = C_bn (a^n - g^n),  a^n = heave + d2/dt2 (C_nv r^v)               (g)

and the outputs are the truth model's forward map of the inputs plus white noise
(:class:`recal.sim.simulate.NoiseSpec` densities), then, with ``VesselSpec.output_filter``, the
unit's own low-pass (:class:`OutputFilter`: a FOG's 1 kHz output through a second-order filter,
which makes its noise coloured). The vessel does not sail: transport rate and
Coriolis acceleration are zero outside ``transit`` segments (a unit under way at constant speed
sees the Eotvos effect, about 75 ug at 5 m/s, which the detector cannot tell from gravity; the
berth is where the product recalibrates).

A long voyage is simulated in chunks (:func:`vessel_chunks`), so a week at 100 Hz needs no more
memory than a chunk; :func:`simulate_vessel` returns a whole recording as a
:class:`recal.sim.session.Session` (holds = the ``hold`` segments), which
``service.capture_sim.session_to_kvh`` encodes as KVH frames. Pure numpy, no I/O.

The spec's types (:class:`SeaState`, :class:`Segment`, :class:`OutputFilter`, :class:`VesselSpec`)
live in :mod:`recal.sim.vessel_spec` and are still importable from here; the schedule evaluated at
any times and the exact inputs live in :mod:`recal.sim.vessel_motion`.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, replace

import numpy as np
from scipy.signal import lfilter

from recal.errors import RecalInputError
from recal.model.coefficients import CoefficientSet
from recal.model.reference import normal_gravity_g
from recal.nav.navigation import ENU_FROM_NED, euler_angles
from recal.nav.trajectory import dcm_zyx
from recal.sim.session import MAX_SAMPLES, Session, sample_context
from recal.sim.simulate import NoiseSpec, truth_model
from recal.sim.vessel_motion import KNOT_M_S, Schedule, vessel_inputs
from recal.sim.vessel_spec import (  # noqa: F401 - the names recal.sim.vessel gave before its split
    OutputFilter,
    SeaState,
    Segment,
    SegmentKind,
    VesselSpec,
)


@dataclass(frozen=True, eq=False)
class VesselRecording:
    """A simulated recording (``session``) and its truth.

    rpy_deg: (N, 3) roll, pitch, yaw of the IMU in NED at each sample's time stamp;
    segment: (N,) index of the segment each sample lies in; kinds: the segments' kinds.
    """

    session: Session
    rpy_deg: np.ndarray
    segment: np.ndarray
    spec: VesselSpec

    @property
    def time_s(self) -> np.ndarray:
        return self.session.time_s


def ship_track(
    spec: VesselSpec,
    time_s: np.ndarray,
    latitude_deg: float = 45.0,
    longitude_deg: float = 0.0,
    height_m: float = 0.0,
    seed: int = 0,
) -> dict[str, np.ndarray]:
    """What the ship's own sensors say at ``time_s`` (s from the start) of the recording
    :func:`vessel_chunks` makes of ``spec`` with this ``seed``: ``latitude_deg``,
    ``longitude_deg`` and ``height_m`` of its GNSS antenna (the hull's centre of rotation),
    ``sog_kn`` and ``cog_deg`` (speed and course over ground) and ``heading_deg`` (true heading,
    the sea's yaw swing and slow heading changes included), each (N,). Pure numbers: the NMEA
    sentences are written by the caller (service.cli.simulate_vessel)."""
    from recal.detect.underway import EARTH_RADIUS_M as R

    sched = Schedule(spec, seed)
    t = np.asarray(time_s, dtype=float)
    att = sched.attitude(t)
    tr = sched.track(t, att["segment"])
    lat = latitude_deg + np.degrees(tr["north"] / R)
    mid = np.radians(0.5 * (latitude_deg + lat))  # a straight course: cos at the mean latitude
    lon = longitude_deg + np.degrees(tr["east"] / (R * np.cos(mid)))
    return {
        "latitude_deg": lat,
        "longitude_deg": (lon + 180.0) % 360.0 - 180.0,
        "height_m": np.full(len(t), float(height_m)),
        "sog_kn": tr["speed"] / KNOT_M_S,
        "cog_deg": np.degrees(tr["course"]) % 360.0,
        "heading_deg": np.degrees(att["heading"]) % 360.0,
    }


def _check(spec: VesselSpec, rate_hz: float, latitude_deg: float) -> None:
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise RecalInputError(f"rate must be positive, not {rate_hz}")
    if not -89.0 <= latitude_deg <= 89.0:
        raise RecalInputError(f"latitude {latitude_deg} deg: a vessel needs |latitude| <= 89")
    if spec.duration_s * rate_hz < 2:
        raise RecalInputError("the schedule needs at least two samples")


@dataclass(frozen=True)
class VesselChunk:
    """One chunk of a long recording: time stamps (s), outputs, temperature and the truth."""

    time_s: np.ndarray
    gyro_out: np.ndarray
    accel_out: np.ndarray
    temperature_c: np.ndarray
    gyro_in_dph: np.ndarray
    accel_in_g: np.ndarray
    C_nb: np.ndarray  # (N, 3, 3) at the stamps
    segment: np.ndarray  # (N,) segment index


def vessel_chunks(
    truth: CoefficientSet,
    spec: VesselSpec,
    latitude_deg: float = 45.0,
    height_m: float = 0.0,
    rate_hz: float = 100.0,
    noise: NoiseSpec | None = None,
    temperature_c: float = 25.0,
    seed: int = 0,
    chunk_s: float = 600.0,
) -> Iterator[VesselChunk]:
    """The recording of ``spec`` in chunks of ``chunk_s`` seconds (the last one shorter).

    Sample i has time stamp i / rate_hz and the inputs at the middle of its interval. Each chunk
    draws its noise from its own generator (seed, chunk index), so the recording does not depend
    on anything but the seed and the chunk length. The Gauss-Markov bias of ``noise`` and the
    output filter (``spec.output_filter``) carry their state from chunk to chunk.
    """
    noise = noise if noise is not None else NoiseSpec(arw_deg_rt_h=0.012, vrw_ug_rt_hz=20.0)
    _check(spec, rate_hz, latitude_deg)
    sched = Schedule(spec, seed)
    g = normal_gravity_g(latitude_deg, height_m)
    n_total = round(spec.duration_s * rate_hz)
    per_chunk = max(1, round(chunk_s * rate_hz))
    noise_at_rate = replace(noise, rate_hz=rate_hz)
    models = {s: truth_model(truth, s) for s in ("gyro", "accel")}
    gm_state = {s: np.zeros(3) for s in ("gyro", "accel")}
    gm_phi = math.exp(-1.0 / (noise.gm_tau_s * rate_hz)) if noise.gm_tau_s > 0 else 0.0
    lowpass = spec.output_filter
    if lowpass is not None:
        lowpass.coefficients(rate_hz)  # a cutoff above half the rate is bad input before any work
    filter_state: dict[str, np.ndarray | None] = {"gyro": None, "accel": None}
    for k, i0 in enumerate(range(0, n_total, per_chunk)):
        i1 = min(n_total, i0 + per_chunk)
        idx = np.arange(i0, i1)
        t = idx / rate_hz
        gyro_in, accel_in, _ = vessel_inputs(sched, (idx + 0.5) / rate_hz, latitude_deg, g)
        att = sched.attitude(t)
        C_nb = dcm_zyx(att["roll"], att["pitch"], att["heading"]) @ att["C_vb"]
        rng = np.random.default_rng([seed, k])
        temp = np.full(len(t), float(temperature_c))
        ctx = sample_context(t, temp, accel_in)
        out = {}
        for sensor, x in (("gyro", gyro_in), ("accel", accel_in)):
            theta, model = models[sensor]
            noisy = x + rng.normal(size=x.shape) * noise_at_rate.per_sample_sigma(sensor)
            gm = noise.gauss_markov_sigma(sensor)
            if gm > 0:
                if k == 0:
                    gm_state[sensor] = rng.normal(size=3) * gm
                drive = rng.normal(size=x.shape) * (gm * math.sqrt(1.0 - gm_phi**2))
                # b_i = phi^(i+1) b_-1 + sum_j phi^(i-j) drive_j: a first-order recursion, in
                # closed form per chunk (scipy's lfilter with an initial state)
                b, _zf = lfilter([1.0], [1.0, -gm_phi], drive, axis=0,
                                 zi=(gm_phi * gm_state[sensor])[None, :])  # fmt: skip
                gm_state[sensor] = b[-1]
                noisy = noisy + b
            out[sensor] = model.forward(theta, noisy, ctx)[0]
            if lowpass is not None:  # the unit's own low-pass, on the whole output
                out[sensor], filter_state[sensor] = lowpass.apply(
                    out[sensor], rate_hz, filter_state[sensor]
                )
        yield VesselChunk(t, out["gyro"], out["accel"], temp, gyro_in, accel_in, C_nb,
                          att["segment"])  # fmt: skip


def simulate_vessel(
    truth: CoefficientSet,
    spec: VesselSpec | None = None,
    latitude_deg: float = 45.0,
    height_m: float = 0.0,
    rate_hz: float = 100.0,
    noise: NoiseSpec | None = None,
    temperature_c: float = 25.0,
    seed: int = 0,
) -> VesselRecording:
    """Every sample of ``spec`` (default: 12 berth holds of 10 min with 30-degree turns of 60 s
    in a 0.3-degree sea) as one :class:`VesselRecording`. ``noise`` defaults to a KVH
    1750-class unit: ARW 0.012 deg/sqrt(h), VRW 20 ug/sqrt(Hz)."""
    spec = spec or VesselSpec.berth()
    _check(spec, rate_hz, latitude_deg)
    N = round(spec.duration_s * rate_hz)
    if N > MAX_SAMPLES:
        raise RecalInputError(
            f"the recording would have {N} samples (limit {MAX_SAMPLES}): lower the rate, or "
            "stream it with vessel_chunks"
        )
    chunks = list(
        vessel_chunks(
            truth,
            spec,
            latitude_deg,
            height_m,
            rate_hz,
            noise,
            temperature_c,
            seed,
            chunk_s=max(1.0, spec.duration_s),
        )  # fmt: skip
    )
    c = chunks[0] if len(chunks) == 1 else _concat(chunks)
    seg = c.segment
    holds = np.flatnonzero(np.array([s.kind == "hold" for s in spec.segments]))
    first, last = [], []
    for h in holds:  # a loop over segments, not samples
        where = np.flatnonzero(seg == h)
        if len(where) >= 2:
            first.append(where[0])
            last.append(where[-1])
    hold_first, hold_last = np.array(first, dtype=np.int64), np.array(last, dtype=np.int64)
    session = Session(
        time_s=c.time_s,
        gyro_out=c.gyro_out,
        accel_out=c.accel_out,
        temperature_c=c.temperature_c,
        static=np.isin(seg, holds),
        gyro_in_dph=c.gyro_in_dph,
        accel_in_g=c.accel_in_g,
        hold_first=hold_first,
        hold_last=hold_last,
        orientations=ENU_FROM_NED @ c.C_nb[hold_first],
        rate_hz=float(rate_hz),
        latitude_deg=float(latitude_deg),
        height_m=float(height_m),
        gravity_g=normal_gravity_g(latitude_deg, height_m),
    )
    rpy = np.degrees(euler_angles(c.C_nb))
    return VesselRecording(session, rpy, seg, spec)


def _concat(chunks: list[VesselChunk]) -> VesselChunk:
    return VesselChunk(*(np.concatenate([getattr(c, f) for c in chunks]) for f in (
        "time_s", "gyro_out", "accel_out", "temperature_c", "gyro_in_dph", "accel_in_g", "C_nb",
        "segment")))  # fmt: skip


def random_hull_unit(rng: np.random.Generator) -> CoefficientSet:
    """A navigation-grade unit in deg/h and g for hull simulations: scale factors within 500 ppm
    of 1, gyro biases within 1 deg/h, accel biases within 1 mg, misalignments within 0.3 mrad
    (uniform draws from ``rng``, in that order), no quadratic term."""
    return CoefficientSet({
        "gyro.scale": 1.0 + rng.uniform(-5e-4, 5e-4, 3),
        "gyro.bias": rng.uniform(-1.0, 1.0, 3),
        "gyro.misalignment": rng.uniform(-3e-4, 3e-4, 6),
        "accel.scale": 1.0 + rng.uniform(-5e-4, 5e-4, 3),
        "accel.bias": rng.uniform(-1e-3, 1e-3, 3),
        "accel.misalignment": rng.uniform(-3e-4, 3e-4, 6),
        "accel.quadratic": np.zeros(3),
    })  # fmt: skip
