"""``[can] hitch_status_address``: the sender the link takes the rear hitch status (the lift) from. An integrator's
finding: ``LinkConfig.hitch_status_address`` existed (the thesis tractor's TECU sent it from 240) but no service
setting reached it, so a tractor whose TECU sends it could not be used."""

from __future__ import annotations

import tempfile
import uuid

import pytest

from bridge.service.config import ServiceConfig, ServiceConfigError, load_service_config
from bridge.service.machine import start_can


def test_default_is_the_cylinder_ecu_and_a_file_or_a_flag_sets_it(tmp_path):
    assert load_service_config().hitch_status_address is None
    f = tmp_path / "service.toml"
    f.write_text("[can]\nsimulate_ecu = false\nhitch_status_address = 240\n")
    assert load_service_config(f).hitch_status_address == 240
    assert load_service_config(f, hitch_status_address=7).hitch_status_address == 7
    assert load_service_config(hitch_status_address=169).hitch_status_address == 169  # the simulated ECU's own


@pytest.mark.parametrize("bad", [254, 255, -1, "240", 240.0, True])
def test_a_value_outside_0_to_253_is_refused_naming_the_field_and_the_range(bad):
    with pytest.raises(ServiceConfigError, match=r"hitch_status_address .*253"):
        load_service_config(simulate_ecu=False, hitch_status_address=bad)


def test_another_sender_than_the_simulated_ecu_is_refused_with_the_simulated_ecu():
    """The simulated cylinder ECU sends the rear hitch status from 169: a link listening to 240 would only ever
    report the lift stale."""
    with pytest.raises(ServiceConfigError, match=r"hitch_status_address 240: the simulated cylinder ECU.*169"):
        load_service_config(hitch_status_address=240)


@pytest.mark.parametrize("address, source, period_s", [(None, 169, 0.01), (240, 240, 0.1)])
def test_the_setting_reaches_the_link(address, source, period_s):
    cfg = ServiceConfig(
        data_dir=tempfile.mkdtemp(),
        can_channel=f"hitch-status-{uuid.uuid4().hex}",
        simulate_ecu=address is None,
        hitch_status_address=address,
    )
    parts = start_can(cfg)
    try:
        assert parts.link.config.hitch_status_address == address
        assert parts.link.config.hitch_source == source
        assert parts.link.config.hitch_status_period_s == period_s
    finally:
        parts.close()


def test_the_period_defaults_to_the_standards_100_ms_from_a_tractor_ecu_and_a_file_sets_it(tmp_path):
    """A review: the link took a 10 Hz TECU's hitch status for a 100 Hz sender, so a node sending as 240 at
    15 times the TECU's rate stayed under the rate check (1.8 × 100/s) and was taken as the lift."""
    assert load_service_config().hitch_status_period() == 0.01
    f = tmp_path / "service.toml"
    f.write_text("[can]\nsimulate_ecu = false\nhitch_status_address = 240\n")
    assert load_service_config(f).hitch_status_period() == 0.1
    f.write_text("[can]\nsimulate_ecu = false\nhitch_status_address = 240\nhitch_status_period_s = 0.02\n")
    assert load_service_config(f).hitch_status_period() == 0.02


@pytest.mark.parametrize("bad", [0.0, 2.0, True, "0.1"])
def test_a_period_out_of_range_is_refused_naming_the_field_and_the_range(bad):
    with pytest.raises(ServiceConfigError, match=r"hitch_status_period_s"):
        load_service_config(simulate_ecu=False, hitch_status_address=240, hitch_status_period_s=bad)


def test_a_spoof_beside_a_10_hz_tractor_ecu_is_refused_once_the_period_is_known(model):
    """The review's case at the link: the TECU (240) at 10 Hz, a node sending as 240 at 150/s one 0.4 % step
    off; with the standard's 100 ms the spoof is refused within 0.2 s and the lift stays the TECU's."""
    from bridge.isobus.codec import RearHitchStatus
    from bridge.link.state import LinkConfig, MeasurementAssembler
    from planner.model.sensors import SensorScaling

    cfg = load_service_config(simulate_ecu=False, hitch_status_address=240)
    link = LinkConfig(hitch_status_address=240, hitch_status_period_s=cfg.hitch_status_period(), bus_timestamps=True)
    rx = MeasurementAssembler(model, SensorScaling(model.profile), link, lambda **_: None)
    taken = []
    for k in range(300):  # 2 s at 150/s, the TECU's frames among them every 0.1 s
        t = k / 150
        own = k % 15 == 0
        rx.on_hitch_status(RearHitchStatus(position=0.5 if own else 0.504), t, stamp_s=t)
        if rx._hitch is not None and rx._hitch[0] == t:
            taken.append((t, own))
    assert all(own for t, own in taken if t > 0.2), taken
    assert "rear hitch status arrives" in rx.last_problem and "hitch_status_period_s" in rx.last_problem


def test_a_period_the_simulated_ecu_does_not_send_at_or_one_the_stale_limit_never_lets_through_is_refused():
    """A review: hitch_status_period_s = 0.1 with the simulated ECU (it sends every 10 ms) was accepted and every
    lift frame was refused as two nodes; a period of 0.5 s beside stale_timeout_s 0.2 s had the lift always stale."""
    from bridge.service.config import SIM_HITCH_STATUS_PERIOD_S
    from bridge.sim.can_node import EcuNodeConfig

    assert SIM_HITCH_STATUS_PERIOD_S == EcuNodeConfig().hitch_status_period_s
    with pytest.raises(ServiceConfigError, match=r"hitch_status_period_s 0.1 s: the simulated cylinder ECU .* 0.01 s"):
        load_service_config(hitch_status_period_s=0.1)
    assert load_service_config(hitch_status_period_s=0.01).hitch_status_period() == 0.01
    with pytest.raises(ServiceConfigError, match=r"hitch_status_period_s 0.5 s: not below stale_timeout_s = 0.2 s"):
        load_service_config(simulate_ecu=False, hitch_status_address=240, hitch_status_period_s=0.5)
    with pytest.raises(ServiceConfigError, match=r"0.1 s \(its default from a sender other than the cylinder ECU\)"):
        load_service_config(simulate_ecu=False, hitch_status_address=240, stale_timeout_s=0.1)
