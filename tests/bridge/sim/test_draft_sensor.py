"""The lower-link draft pins: filter time constant, noise, quantisation, and the rear hitch status frame."""

import math

import numpy as np
import pytest

from bridge.isobus.codec import decode, encode
from bridge.isobus.j1939 import Switch
from bridge.isobus.messages import RearHitchStatus
from bridge.sim.draft_sensor import DraftPinConfig, DraftPinError, DraftPins, rear_hitch_status
from planner.errors import HitchInputError


def _step(tau_s: float, dt: float, t_end: float) -> tuple[np.ndarray, np.ndarray]:
    pins = DraftPins(DraftPinConfig(noise_rms_n=0.0, tau_s=tau_s, resolution_n=0.0))
    pins.measure(0.0, 0.0)
    t = np.arange(1, int(round(t_end / dt)) + 1) * dt
    y = np.array([pins.measure(float(tk), 10_000.0).draft_n for tk in t])
    return t, y


@pytest.mark.parametrize("tau_s", [0.05, 0.2, 1.0])
def test_step_reaches_63_percent_at_tau(tau_s):
    dt = tau_s / 100
    t, y = _step(tau_s, dt, 5 * tau_s)
    at_tau = y[int(round(tau_s / dt)) - 1]
    assert at_tau == pytest.approx(10_000.0 * (1 - math.exp(-1)), rel=1e-9)  # 63.2 %
    assert y[-1] == pytest.approx(10_000.0 * (1 - math.exp(-5)), rel=1e-9)
    assert np.all(np.diff(y) > 0)


def test_step_time_constant_does_not_depend_on_the_sample_step():
    _, coarse = _step(0.2, 0.02, 0.2)
    _, fine = _step(0.2, 0.001, 0.2)
    assert coarse[-1] == pytest.approx(fine[-1], rel=1e-9)


def test_noise_rms_as_configured_unfiltered():
    pins = DraftPins(DraftPinConfig(noise_rms_n=80.0, tau_s=0.0, resolution_n=0.0, seed=5))
    r = [pins.measure(0.01 * k, 20_000.0) for k in range(4000)]
    left = np.array([x.left_n for x in r])
    assert left.mean() == pytest.approx(10_000.0, abs=5.0)  # half the draft on each pin
    assert left.std() == pytest.approx(80.0, rel=0.05)
    draft = np.array([x.draft_n for x in r])
    assert draft.std() == pytest.approx(80.0 * math.sqrt(2), rel=0.05)  # two independent pins


def test_filter_reduces_noise_by_the_first_order_factor():
    # white noise σ through x += α(u - x): stationary σ_x = σ·sqrt(α/(2 - α))
    dt, tau, sigma = 0.01, 0.1, 100.0
    pins = DraftPins(DraftPinConfig(noise_rms_n=sigma, tau_s=tau, resolution_n=0.0, seed=11))
    y = np.array([pins.measure(dt * k, 0.0).left_n for k in range(20_000)])[200:]
    a = 1 - math.exp(-dt / tau)
    assert y.std() == pytest.approx(sigma * math.sqrt(a / (2 - a)), rel=0.1)


def test_readings_are_quantised():
    pins = DraftPins(DraftPinConfig(noise_rms_n=30.0, tau_s=0.05, resolution_n=25.0, seed=2))
    for k in range(200):
        r = pins.measure(0.01 * k, 12_345.0)
        assert r.left_n / 25.0 == pytest.approx(round(r.left_n / 25.0), abs=1e-9)
        assert r.right_n / 25.0 == pytest.approx(round(r.right_n / 25.0), abs=1e-9)


def test_seeded_noise_repeats():
    def run(seed):
        p = DraftPins(DraftPinConfig(seed=seed))
        return [p.measure(0.01 * k, 5000.0).draft_n for k in range(50)]

    assert run(1) == run(1)
    assert run(1) != run(2)


@pytest.mark.parametrize(
    ("call", "field"),
    [
        (lambda: DraftPinConfig(noise_rms_n=-1.0), "noise_rms_n"),
        (lambda: DraftPinConfig(tau_s=math.inf), "tau_s"),
        (lambda: DraftPinConfig(resolution_n=5000.0), "resolution_n"),
        (lambda: DraftPinConfig(seed=1.5), "seed"),  # type: ignore[arg-type]
        (lambda: DraftPins().measure(0.0, math.nan), "draft_n"),
        (lambda: rear_hitch_status(1000.0, nominal_force_n=0.0), "nominal_force_n"),
        (lambda: rear_hitch_status(1000.0, nominal_force_n=1e4, position=1.5), "position"),
    ],
)
def test_bad_inputs_name_the_field(call, field):
    with pytest.raises(DraftPinError, match=field) as info:
        call()
    assert isinstance(info.value, HitchInputError)


def test_time_must_not_go_back():
    pins = DraftPins()
    pins.measure(1.0, 0.0)
    with pytest.raises(DraftPinError, match="t = 0.5"):
        pins.measure(0.5, 0.0)


def test_rear_hitch_status_carries_the_draft_through_the_codec():
    status = rear_hitch_status(21_530.0, nominal_force_n=40_000.0, position=0.4, in_work=Switch.ON)
    assert status.draft_n == 21_530.0
    assert status.nominal_lower_link_force == pytest.approx(21_530.0 / 40_000.0)
    back = decode(encode(status))
    assert isinstance(back, RearHitchStatus)
    assert back.draft_n == pytest.approx(21_530.0, abs=5.0)  # 10 N/bit
    assert back.nominal_lower_link_force == pytest.approx(0.538, abs=0.004)  # 0.8 %/bit
    assert back.in_work is Switch.ON


def test_rear_hitch_status_out_of_range_is_not_available():
    status = rear_hitch_status(400_000.0, nominal_force_n=300_000.0)
    assert status.draft_n is None  # beyond 322 550 N
    assert status.nominal_lower_link_force is None  # 1.33 > 1
    back = decode(encode(status))
    assert isinstance(back, RearHitchStatus)
    assert back.draft_n is None and back.nominal_lower_link_force is None
