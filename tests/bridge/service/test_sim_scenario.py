"""``sim_scenario`` (config ``[can]``, ``hitch serve --sim-scenario``): the service's simulated tractor drives over
a track scenario's terrain, so levelling can be tried on the service and in the terminal (a field trial: the
service's twin was always flat, and only ``hitch sim track`` rolled). Truth: the scenario's own cross slope
(``levelling-inside``: 0.035 rad at 0.02 Hz + 0.015 rad at 0.1 Hz, any 6 s of it spans at least 12.9 mrad),
the level frame's definition (target roll = roll_level + the slope sensor's roll) and the measured hitch roll."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from bridge.service.config import ServiceConfig, ServiceConfigError, load_service_config
from bridge.service.server import HitchService
from tests.helpers import wait_until
from tests.integration.service_process import free_port


def _start(tmp_path, **kw) -> HitchService:
    cfg = ServiceConfig(listen=[f"tcp/127.0.0.1:{free_port()}"], data_dir=tmp_path, planning_processes=0, **kw)
    svc = HitchService(cfg).start()
    assert wait_until(lambda: ((svc.latest_state or {}).get("ecu") or {}).get("online")), "no state from the core"
    return svc


def _call(svc, key, payload=None):
    return svc.api.handle(key, json.dumps(payload or {}))


@pytest.mark.slow
def test_levelling_on_the_service_over_a_rolling_scenario(tmp_path):
    svc = _start(tmp_path, sim_scenario="levelling-inside")
    states: list[dict] = []
    svc.add_listener("state", states.append)
    try:
        ok, cfg = _call(svc, "config")
        assert ok and cfg["can"]["simulated_ground_speed"] == pytest.approx(2.2222), cfg  # the scenario's own speed
        assert cfg["can"]["simulated_scenario"] == "levelling-inside" and cfg["can"]["simulated_field"] is None
        ok, reply = _call(svc, "track/start", {"dof": ["roll"], "frame": "level", "ttl_ms": 500})
        assert ok, reply  # the slope sensor is on the bus (flat: it is too, reading 0)
        session = reply["session"]
        t_end = time.monotonic() + 6.0
        seq = 0
        while time.monotonic() < t_end:
            seq += 1
            ok, reply = _call(svc, "track/setpoint", {"session": session, "seq": seq, "pose": {"roll": 0.0}})
            assert ok, reply
            time.sleep(0.02)
        live = [s for s in states if s.get("track") and s["track"].get("target")]
        target = np.array([s["track"]["target"]["roll"] for s in live])
        measured = np.array([s["pose"]["roll"] for s in live])
        assert len(live) > 100
        # the tractor rolls: the level frame's target follows the slope sensor (flat ground: a constant 0)
        assert np.ptp(target) > 0.008, np.ptp(target)
        # and the hitch follows it (the closed loop's lag aside)
        assert np.ptp(measured) > 0.006, np.ptp(measured)
        assert np.sqrt(np.mean((measured[50:] - target[50:]) ** 2)) < 0.006
        ok, _ = _call(svc, "track/stop", {"session": session})
        assert ok
    finally:
        svc.close()


def test_a_scenario_is_checked_before_the_service_starts_and_not_with_a_field():
    with pytest.raises(ServiceConfigError, match="sim_scenario 'nope': .*not found; built-in scenarios: .*levelling"):
        load_service_config(None, sim_scenario="nope")
    with pytest.raises(ServiceConfigError, match="sim_field 'chisel' and sim_scenario 'levelling': give one"):
        load_service_config(None, sim_field="chisel", sim_scenario="levelling")
    assert load_service_config(None, sim_scenario="levelling").sim_scenario == "levelling"


def test_a_flags_terrain_wins_over_the_other_one_in_the_config_file(tmp_path):
    """A review: a config file with [can] sim_scenario and hitch serve --sim-field chisel was refused "give one";
    a flag overrides the file (as --implement does), and sim_field and sim_scenario are one choice."""
    conf = tmp_path / "service.toml"
    conf.write_text('[can]\nsim_scenario = "levelling"\n')
    cfg = load_service_config(conf, sim_field="chisel")
    assert (cfg.sim_field, cfg.sim_scenario) == ("chisel", None)
    conf.write_text('[can]\nsim_field = "chisel"\n')
    cfg = load_service_config(conf, sim_scenario="terrain")
    assert (cfg.sim_field, cfg.sim_scenario) == (None, "terrain")
    with pytest.raises(ServiceConfigError, match="give one"):  # both flags: still refused
        load_service_config(conf, sim_scenario="terrain", sim_field="chisel")


def test_a_scenario_without_a_simulated_tractor_is_said_at_start_not_ignored():
    """A review: hitch serve --no-sim-ecu --sim-scenario levelling started without a word about the scenario."""
    from bridge.service.work import unused_sim_terrain

    assert unused_sim_terrain(load_service_config(None, sim_scenario="levelling")) == []
    (w,) = unused_sim_terrain(load_service_config(None, sim_scenario="levelling", simulate_ecu=False))
    assert "sim_scenario 'levelling'" in w and "not used" in w and "--no-sim-ecu" in w
    assert unused_sim_terrain(load_service_config(None, simulate_ecu=False)) == []
