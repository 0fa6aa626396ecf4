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


@pytest.mark.parametrize("address, source", [(None, 169), (240, 240)])
def test_the_setting_reaches_the_link(address, source):
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
    finally:
        parts.close()
