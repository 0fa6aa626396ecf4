"""The terrain twin against independent geometry: planes, rotations, lstsq, statistics."""

import math

import numpy as np
import pytest

from bridge.isobus.codec import FigureOfMerit, decode, encode
from bridge.isobus.messages import GroundDistance, SlopeSensorInformation, WheelBasedSpeed
from bridge.sim.sensors import TwinSensors
from bridge.sim.terrain import (
    CrossSlopeWave,
    RowSignal,
    SampledGround,
    SineGround,
    SpeedProfile,
    TerrainError,
    TerrainTwin,
    TractorGeometry,
    Undulation,
    body_attitude,
    contact_plane,
)

V = 8 / 3.6


def twin(ground, suspension="rigid", speed=V, **kw):
    return TerrainTwin(
        ground=ground, speed=SpeedProfile.constant(speed), tractor=TractorGeometry(2.7, 1.8, suspension), **kw
    )


def euler_rotation(pitch, roll):
    """Independent: world (s forward, u left, z up) <- body, SAE J670 yaw 0 (pitch + nose up, roll + right down)."""
    ry = np.array([[math.cos(pitch), 0, -math.sin(pitch)], [0, 1, 0], [math.sin(pitch), 0, math.cos(pitch)]])
    rx = np.array([[1, 0, 0], [0, math.cos(roll), -math.sin(roll)], [0, math.sin(roll), math.cos(roll)]])
    return ry @ rx


@pytest.mark.parametrize("suspension", ["rigid", "oscillating"])
def test_flat_ground_gives_zero_roll_pitch_and_ground(suspension):
    tw = twin(SineGround(), suspension)
    for t in np.linspace(0, 60, 13):
        st = tw.state(float(t))
        assert (st.pitch_rad, st.roll_rad, st.pitch_rate_rad_s, st.roll_rate_rad_s) == (0.0, 0.0, 0.0, 0.0)
        assert tw.implement_ground_z(float(t)) == 0.0


@pytest.mark.parametrize("suspension", ["rigid", "oscillating"])
@pytest.mark.parametrize("slope", [-0.1, 0.03, 0.1, 0.3])
def test_constant_side_slope_gives_that_roll(suspension, slope):
    tw = twin(SineGround(cross_slope_rad_0=slope), suspension)
    st = tw.state(12.3)
    assert st.roll_rad == pytest.approx(slope, abs=1e-12)  # + left side higher = right side down
    assert st.pitch_rad == pytest.approx(0.0, abs=1e-15)
    assert tw.implement_ground_z(12.3, lateral_m=0.7) == pytest.approx(0.0, abs=1e-12)  # same plane


@pytest.mark.parametrize("grade", [-0.2, 0.05, 0.1])
def test_constant_grade_gives_that_pitch(grade):
    tw = twin(SineGround(grade_rad=grade))
    st = tw.state(7.0)
    assert st.pitch_rad == pytest.approx(grade, abs=1e-12)
    assert st.roll_rad == pytest.approx(0.0, abs=1e-15)
    assert st.rear_axle_z_m == pytest.approx(7.0 * V * math.tan(grade), abs=1e-9)


def test_rigid_plane_matches_numpy_lstsq_through_the_four_contacts():
    rng = np.random.default_rng(4)
    geo = TractorGeometry(2.7, 1.8, "rigid")
    for _ in range(200):
        z = rng.uniform(-0.1, 0.1, 4)  # rl, rr, fl, fr
        pts = np.array([[0, 0.9], [0, -0.9], [2.7, 0.9], [2.7, -0.9]])  # (s - s_r, u)
        A = np.column_stack([np.ones(4), pts])
        (a0, b_ref, c_ref), *_ = np.linalg.lstsq(A, z, rcond=None)
        z0, b, c = contact_plane(*z, geo)
        assert (z0, b, c) == pytest.approx((a0, b_ref, c_ref), abs=1e-12)


def test_oscillating_axle_plane_contains_the_rear_contacts_and_the_front_pivot():
    rng = np.random.default_rng(5)
    geo = TractorGeometry(2.7, 1.8, "oscillating")
    for _ in range(100):
        zrl, zrr, zfl, zfr = rng.uniform(-0.1, 0.1, 4)
        z0, b, c = contact_plane(zrl, zrr, zfl, zfr, geo)
        assert z0 + c * 0.9 == pytest.approx(zrl, abs=1e-12)
        assert z0 - c * 0.9 == pytest.approx(zrr, abs=1e-12)
        assert z0 + b * 2.7 == pytest.approx((zfl + zfr) / 2, abs=1e-12)  # pivot midway between the front wheels


def test_body_attitude_recovers_the_euler_angles_of_a_rotated_body():
    rng = np.random.default_rng(6)
    for _ in range(200):
        pitch, roll = rng.uniform(-0.4, 0.4, 2)
        R = euler_rotation(pitch, roll)
        n = R @ np.array([0.0, 0.0, 1.0])  # the body's contact-plane normal
        b, c = -n[0] / n[2], -n[1] / n[2]  # plane z = b s + c u
        att = body_attitude(b, c)
        assert att.pitch_rad == pytest.approx(pitch, abs=1e-12)
        assert att.roll_rad == pytest.approx(roll, abs=1e-12)


def test_a_tractor_on_an_undulation_follows_the_closed_form_of_its_wheel_heights():
    und = (Undulation(0.03, 7.0), Undulation(0.02, 19.0, 0.5))
    tw = twin(SineGround(undulations=und))
    for t in np.linspace(0.0, 30.0, 31):
        s = V * float(t)
        zr = sum(u.amplitude_m * math.sin(2 * math.pi * s / u.wavelength_m + u.phase_rad) for u in und)
        zf = sum(u.amplitude_m * math.sin(2 * math.pi * (s + 2.7) / u.wavelength_m + u.phase_rad) for u in und)
        st = tw.state(float(t))
        assert st.pitch_rad == pytest.approx(math.atan((zf - zr) / 2.7), abs=1e-12)
        assert st.roll_rad == pytest.approx(0.0, abs=1e-15)
        zi = sum(u.amplitude_m * math.sin(2 * math.pi * (s - 1.2) / u.wavelength_m + u.phase_rad) for u in und)
        expected = zi - (zr - (zf - zr) / 2.7 * 1.2)  # ground minus the contact plane extended 1.2 m back
        assert tw.implement_ground_z(float(t)) == pytest.approx(expected, abs=1e-12)
        assert abs(tw.implement_ground_z(float(t))) < 0.2
        assert tw.ground_distance_m(float(t), 0.5) == pytest.approx(0.5 - expected, abs=1e-12)


def test_side_slope_wave_roll_and_rate():
    wave = CrossSlopeWave(0.1, 44.44)
    tw = twin(SineGround(cross_waves=(wave,)), "oscillating")
    f = V / 44.44  # Hz
    for t in np.linspace(1.0, 40.0, 9):
        c = 0.1 * math.sin(2 * math.pi * V * float(t) / 44.44)
        st = tw.state(float(t))
        assert st.roll_rad == pytest.approx(c, abs=1e-12)
        assert st.roll_rate_rad_s == pytest.approx(
            0.1 * 2 * math.pi * f * math.cos(2 * math.pi * f * float(t)), abs=1e-5
        )


def test_sampled_profile_interpolates_and_holds_its_ends():
    g = SampledGround((0.0, 10.0, 20.0), (0.0, 0.1, 0.1), (0.0, 0.05, -0.05))
    assert g.profile_m(5.0) == pytest.approx(0.05)
    assert g.cross_slope_rad(15.0) == pytest.approx(0.0)
    assert g.profile_m(-3.0) == 0.0 and g.profile_m(99.0) == pytest.approx(0.1)
    with pytest.raises(TerrainError, match=r"distance_m\[1\] = 0.0 must exceed"):
        SampledGround((0.0, 0.0), (0.0, 0.0))


def test_speed_profile_distance_is_the_exact_integral():
    sp = SpeedProfile((0.0, 10.0, 20.0), (1.0, 3.0, 3.0))
    assert sp.distance_m(10.0) == pytest.approx(20.0)
    assert sp.distance_m(5.0) == pytest.approx(5.0 * 1.5)  # v = 1 + 0.2 t
    assert sp.distance_m(30.0) == pytest.approx(20.0 + 30.0 + 30.0)
    assert sp.speed_m_s(15.0) == 3.0 and sp.speed_m_s(-1.0) == 1.0


def test_row_signal_rms_and_noise_as_configured():
    row = RowSignal(rms_m=0.02, noise_rms_m=0.005, rate_hz=10.0, seed=11)
    tw = twin(SineGround(), row=row)
    t = np.arange(0.0, 900.0, 0.1)  # 9000 camera samples over 2 km
    true = np.array([tw.row_true_offset_m(float(x)) for x in t])
    meas = np.array([tw.row_measured_offset_m(float(x)) for x in t])
    assert np.sqrt(np.mean(true**2)) == pytest.approx(0.02, rel=0.1)
    noise = meas - true
    assert np.sqrt(np.mean(noise**2)) == pytest.approx(0.005, rel=0.05)  # chi-square: 9000 samples, ±1.5 % at 1σ
    assert abs(np.mean(noise)) < 4 * 0.005 / math.sqrt(len(noise))
    # seeded: the same seed gives the same signal, another seed another one
    again = TerrainTwin(speed=SpeedProfile.constant(V), row=RowSignal(rms_m=0.02, noise_rms_m=0.005, seed=11))
    assert again.row_measured_offset_m(123.45) == tw.row_measured_offset_m(123.45)
    other = TerrainTwin(speed=SpeedProfile.constant(V), row=RowSignal(rms_m=0.02, noise_rms_m=0.005, seed=12))
    assert other.row_measured_offset_m(123.45) != tw.row_measured_offset_m(123.45)


def test_row_measurement_updates_at_the_configured_rate():
    for rate in (10.0, 4.0):
        tw = twin(SineGround(), row=RowSignal(rms_m=0.02, noise_rms_m=0.005, rate_hz=rate, seed=3))
        t = np.arange(0.0, 5.0, 0.004)
        v = np.array([tw.row_measured_offset_m(float(x)) for x in t])
        changes = np.flatnonzero(np.diff(v) != 0.0)
        assert len(changes) == pytest.approx(5.0 * rate - 1, abs=1)
        gaps = np.diff(t[changes + 1])
        assert gaps == pytest.approx(np.full(len(gaps), 1.0 / rate), abs=4.5e-3)


def test_row_band_is_spatial_so_the_signal_speeds_up_with_the_tractor():
    row = RowSignal(rms_m=0.02, noise_rms_m=0.0, seed=1)
    slow, fast = twin(SineGround(), speed=4 / 3.6, row=row), twin(SineGround(), speed=8 / 3.6, row=row)
    for t in (3.0, 17.5, 42.0):
        assert fast.row_true_offset_m(t) == pytest.approx(slow.row_true_offset_m(2 * t), abs=1e-12)


def test_a_camera_ahead_of_the_implement_sees_the_row_that_far_ahead():
    # the front-axle camera: wheelbase 2.7 m + implement 1.2 m behind the rear axle = 3.9 m of look-ahead
    under = twin(SineGround(), speed=4 / 3.6, row=RowSignal(rms_m=0.02, noise_rms_m=0.005, seed=5))
    ahead = twin(SineGround(), speed=4 / 3.6, row=RowSignal(rms_m=0.02, noise_rms_m=0.005, seed=5, camera_ahead_m=3.9))
    assert under.row.camera_ahead_m == 0.0  # the default: a camera under the implement, as before
    lead_s = 3.9 / (4 / 3.6)  # the offset seen now is the implement's d / v later
    for k in (20, 77, 131):  # camera samples k at k / 10 Hz, read between the ticks (sample and hold)
        t = k / 10.0 + 0.05
        noise = under.row.noise_m(k)
        assert under.row_measured_offset_m(t) == pytest.approx(under.row_true_offset_m(k / 10.0) + noise, abs=1e-12)
        assert ahead.row_measured_offset_m(t) == pytest.approx(
            ahead.row_true_offset_m(k / 10.0 + lead_s) + noise, abs=1e-12
        )
        assert ahead.row_true_offset_m(t) == under.row_true_offset_m(t)  # the truth stays under the implement
    with pytest.raises(TerrainError, match=r"camera_ahead_m .*\[0, 20\]"):
        RowSignal(camera_ahead_m=-1.0)


def test_scenario_row_camera_ahead_m_reaches_the_twin_and_is_range_checked():
    from bridge.sim.scenario import ScenarioError, scenario_from_dict

    base = {"schema_version": 1, "name": "cam", "duration_s": 10.0, "speed": {"constant_m_s": 1.0}}
    sc = scenario_from_dict({**base, "signals": {"row_camera_ahead_m": 3.9}})
    assert sc.twin.row.camera_ahead_m == 3.9
    assert scenario_from_dict(base).twin.row.camera_ahead_m == 0.0
    with pytest.raises(ScenarioError, match="row_camera_ahead_m"):
        scenario_from_dict({**base, "signals": {"row_camera_ahead_m": 25.0}})


def test_sensor_payloads_encode_and_decode_on_the_bus():
    tw = twin(SineGround(cross_slope_rad_0=0.05, grade_rad=0.02))
    sensors = TwinSensors(tw, slope_latency_s=0.01)
    ssi = decode(encode(sensors.slope(10.0)))
    assert isinstance(ssi, SlopeSensorInformation)
    assert ssi.roll_rad == pytest.approx(0.05, abs=math.radians(0.001) + 1e-9)
    assert ssi.pitch_rad == pytest.approx(0.02, abs=math.radians(0.001) + 1e-9)
    assert ssi.pitch_merit is FigureOfMerit.FULLY_FUNCTIONAL and ssi.latency_s == pytest.approx(0.01)
    wbs = decode(encode(sensors.wheel_speed(10.0)))
    assert isinstance(wbs, WheelBasedSpeed)
    assert wbs.distance_m == pytest.approx(10.0 * V, abs=1e-3) and wbs.speed_m_s == pytest.approx(V, abs=1e-3)
    gd = sensors.ground_distance(10.0, 0.45)
    assert gd.distance_m == pytest.approx(0.45)  # on a plane the implement ground is the contact plane
    back = decode(encode(gd))
    assert isinstance(back, GroundDistance) and back.distance_m == pytest.approx(0.45, abs=0.5e-4)
    assert sensors.ground_distance(10.0, -0.1).merit is FigureOfMerit.ERROR  # below the ground: not a number


def test_bad_inputs_name_the_field_and_range():
    with pytest.raises(TerrainError, match=r"wheelbase_m = 0 is outside the allowed range \(0, 10\]"):
        TractorGeometry(0, 1.8)
    with pytest.raises(TerrainError, match=r"suspension must be 'rigid' or 'oscillating'"):
        TractorGeometry(2.7, 1.8, "soft")  # type: ignore[arg-type]
    with pytest.raises(TerrainError, match=r"rms_m = nan is outside"):
        RowSignal(rms_m=math.nan)
    with pytest.raises(TerrainError, match=r"speed_m_s\[0\] = 20 is outside the allowed range \[0, 15\]"):
        SpeedProfile.constant(20)


def test_a_twin_that_keeps_its_last_contact_plane_answers_as_a_fresh_one():
    """The contact plane is kept for the last distance (a standing tractor computes it once): over random
    times, repeated and out of order, on undulating ground at a changing speed and standing still, one twin
    gives exactly what a fresh twin gives for each call."""
    ground = SineGround(
        grade_rad=0.02,
        cross_slope_rad_0=0.01,
        undulations=(Undulation(0.05, 7.0),),
        cross_waves=(CrossSlopeWave(0.03, 11.0, 0.4),),
    )
    speeds = (SpeedProfile.constant(0.0), SpeedProfile.constant(2.2))

    def fresh(speed: SpeedProfile) -> TerrainTwin:
        return TerrainTwin(ground=ground, speed=speed)

    rng = np.random.default_rng(3)
    for speed in speeds:
        kept = fresh(speed)
        times = rng.uniform(0.0, 20.0, 60)
        for t in np.concatenate([times, times[::-1], np.repeat(times[:10], 3)]):
            t = float(t)
            assert kept.state(t) == fresh(speed).state(t)
            assert kept.ground_distance_m(t, 0.6) == fresh(speed).ground_distance_m(t, 0.6)
            assert kept.ground_ahead_z(t) == fresh(speed).ground_ahead_z(t)
