"""ServiceConfig: embedded defaults, TOML file, flags over file, errors naming the field."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bridge.service.config import ServiceConfig, ServiceConfigError, default_data_dir, load_service_config
from bridge.service.server import build_zenoh_config, to_json_bytes


def test_embedded_defaults_are_a_loopback_peer_with_the_simulated_ecu(monkeypatch, tmp_path):
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path))
    c = load_service_config()
    assert c.mode == "peer" and c.listen == ("tcp/127.0.0.1:7447",) and c.connect == () and not c.scouting
    assert c.prefix == "hitch" and c.key("presets/go") == "hitch/presets/go"
    assert (c.can_interface, c.can_channel, c.simulate_ecu) == ("virtual", "hitch", True)
    assert (c.profile, c.category, c.control_rate, c.state_rate) == ("thesis-t132", None, 50.0, 50.0)
    assert c.feedforward is True
    assert c.data_dir == tmp_path / "hitch-planner" and c.database_path.name == "hitch.sqlite3"
    z = json.loads(build_zenoh_config(c).get_json("scouting/multicast/enabled"))
    assert z is False


def test_default_data_dir_without_xdg():
    assert default_data_dir({}) == Path.home() / ".local" / "share" / "hitch-planner"
    assert default_data_dir({"XDG_DATA_HOME": "/x"}) == Path("/x/hitch-planner")


def test_toml_then_flags(tmp_path):
    f = tmp_path / "svc.toml"
    f.write_text(
        '[zenoh]\nprefix = "fleet/t07/hitch"\nmode = "client"\nconnect = ["tcp/10.0.0.1:7447"]\n'
        '[hitch]\ncontrol_rate = 100.0\nimplement = "cat2-spreader-400"\nfeedforward = false\n'
        "[service]\nworkers = 2\n"
    )
    c = load_service_config(f)
    assert c.prefix == "fleet/t07/hitch" and c.mode == "client" and c.listen == () and c.control_rate == 100.0
    assert c.implement == "cat2-spreader-400" and c.workers == 2 and c.feedforward is False
    c = load_service_config(f, control_rate=40.0, prefix=None)  # a flag wins; None means "not given"
    assert c.control_rate == 40.0 and c.prefix == "fleet/t07/hitch"


@pytest.mark.parametrize(
    "kwargs, text",
    [
        ({"prefix": "fleet/*/hitch"}, "prefix"),
        ({"prefix": "a//b"}, "chunk ''"),
        ({"listen": ["127.0.0.1:7447"]}, "tcp/127.0.0.1:7447"),
        ({"control_rate": 5.0}, "control_rate = 5.0"),
        ({"control_rate": float("nan")}, "control_rate"),
        ({"state_rate": 500.0}, "<= 100"),
        ({"mode": "router"}, "mode"),
        ({"mode": "client"}, "connect: a client needs"),
        ({"mode": "client", "connect": ["tcp/127.0.0.1:1"], "listen": ["tcp/127.0.0.1:2"]}, "a client does not listen"),
        ({"http": "8080"}, "HOST:PORT"),
        ({"http_hosts": ["cab.local"]}, "http_hosts 'cab.local' must be HOST:PORT"),
        ({"http_hosts": ["cab local:80"]}, "http_hosts 'cab local:80'"),
        ({"can_interface": "pcan"}, "can_interface"),
        ({"feedforward": "yes"}, "feedforward"),
        ({"simulate_ecu": 1}, "simulate_ecu"),
        # a fleet trial: these said "invalid port value", "Input should be a valid tuple", pydantic's literal['auto']
        # branches, or "must be HOST:PORT" for a port out of range
        ({"listen": ["tcp/127.0.0.1:99999"]}, "the port 99999 must be a whole number 0…65535"),
        ({"listen": ["tcp/localhost"]}, "the port (none) must be a whole number 0…65535"),
        ({"connect": "tcp/127.0.0.1:7447"}, 'connect must be a list of endpoints such as ["tcp/127.0.0.1:7447"]'),
        ({"user_keys": "yes"}, "user_keys must be \"auto\", true or false, got 'yes'"),
        ({"http": "127.0.0.1:174010"}, "(port 0…65535)"),
        ({"http_hosts": ["cab.local:70000"]}, "(port 0…65535)"),
        ({"lease_s": 0.1}, "lease_s"),
        ({"lease_s": 600}, "lease_s"),
    ],
)
def test_bad_values_name_the_field(kwargs, text):
    with pytest.raises(ServiceConfigError) as ei:
        load_service_config(**kwargs)
    assert text in str(ei.value) and "\n" not in str(ei.value)


def test_bad_toml_is_refused_with_the_key(tmp_path):
    f = tmp_path / "svc.toml"
    f.write_text("[zenoh]\nport = 1\n")
    with pytest.raises(ServiceConfigError, match=r"unknown key zenoh\.port; allowed: mode, listen"):
        load_service_config(f)
    f.write_text("[cluster]\n")
    with pytest.raises(ServiceConfigError, match=r"unknown section \[cluster\]"):
        load_service_config(f)
    f.write_text("[zenoh\n")
    with pytest.raises(ServiceConfigError, match="not valid TOML"):
        load_service_config(f)
    with pytest.raises(ServiceConfigError, match="does not exist"):
        load_service_config(tmp_path / "missing.toml")


def test_replies_are_strict_json():
    out = json.loads(to_json_bytes({"a": float("inf"), "b": [float("nan"), 1.5], "c": {"d": -float("inf")}}))
    assert out == {"a": None, "b": [None, 1.5], "c": {"d": None}}


def test_store_limits_per_user_from_toml_with_errors_naming_the_field(tmp_path):
    assert load_service_config().store_limits().max_maneuvers_per_user == 200
    f = tmp_path / "service.toml"
    f.write_text("[service]\nmax_presets_per_user = 5\nmax_maneuvers_per_user = 3\nmax_script_bytes_per_user = 70000\n")
    limits = load_service_config(f).store_limits()
    assert (limits.max_presets_per_user, limits.max_maneuvers_per_user, limits.max_script_bytes_per_user) == (
        5,
        3,
        70000,
    )
    with pytest.raises(ServiceConfigError, match="max_maneuvers_per_user"):
        load_service_config(max_maneuvers_per_user=0)
    with pytest.raises(ServiceConfigError, match="max_script_bytes_per_user"):
        load_service_config(max_script_bytes_per_user=1000)  # below one script's maximum


def test_every_link_interface_is_a_service_interface():
    """The service accepts every python-can interface the link can open (the loopback hub's
    ``remote`` included), and the ``serve`` option offers the same list."""
    import argparse

    from bridge.cli.service import add_commands
    from bridge.link.realtime import INTERFACES

    for name in INTERFACES:
        assert load_service_config(can_interface=name).can_interface == name
    parser = argparse.ArgumentParser()
    add_commands(parser.add_subparsers(dest="command"))
    serve = parser.parse_args(["serve", "--can-interface", "remote"])
    assert serve.can_interface == "remote"


def test_can_log_rotation_settings_from_toml_and_flags_with_errors_naming_the_field_and_range(tmp_path):
    cfg = load_service_config()
    assert (cfg.can_log, cfg.can_log_max_mb, cfg.can_log_keep) == (None, 50.0, 10)
    f = tmp_path / "service.toml"
    f.write_text('[service]\ncan_log = "bus.blf"\ncan_log_max_mb = 2.5\ncan_log_keep = 3\n')
    cfg = load_service_config(f)
    assert (cfg.can_log.name, cfg.can_log_max_mb, cfg.can_log_keep) == ("bus.blf", 2.5, 3)
    for bad in ({"can_log_max_mb": 0.0}, {"can_log_max_mb": float("nan")}, {"can_log_keep": 0}):
        with pytest.raises(ServiceConfigError, match=next(iter(bad))):
            load_service_config(**bad)


def test_relative_paths_in_a_config_file_are_taken_from_its_folder(tmp_path, monkeypatch):
    """A commissioning engineer's report: ``profile = "../tractor.toml"`` and ``sim_truth = "../truth.toml"`` in
    outdir/service.toml were taken from the working folder ("profile file ../tractor.toml does not exist"). As
    a profile names its tractor, a config file names its files from where it lies; flags stay as typed."""
    (tmp_path / "outdir").mkdir()
    (tmp_path / "elsewhere").mkdir()
    truth = tmp_path / "truth.toml"
    truth.write_text("")
    cfg_file = tmp_path / "outdir" / "service.toml"
    cfg_file.write_text(
        '[hitch]\nprofile = "../tractor.toml"\n[can]\nsim_truth = "../truth.toml"\n'
        '[service]\ndata_dir = "data"\ncan_log = "bus.asc"\n'
    )
    monkeypatch.chdir(tmp_path / "elsewhere")
    cfg = load_service_config(cfg_file)
    assert Path(cfg.profile).resolve() == tmp_path / "tractor.toml"
    assert cfg.sim_truth is not None and cfg.sim_truth.resolve() == truth
    assert cfg.data_dir.resolve() == tmp_path / "outdir" / "data"
    assert cfg.can_log is not None and cfg.can_log.resolve() == tmp_path / "outdir" / "bus.asc"
    assert load_service_config(cfg_file, profile="mine.toml").profile == "mine.toml"  # a flag: as typed
    plain = tmp_path / "outdir" / "plain.toml"
    plain.write_text('[hitch]\nprofile = "thesis-t132"\n')
    assert load_service_config(plain).profile == "thesis-t132"  # a built-in name stays a name


def test_the_config_reference_lists_every_key_the_service_reads():
    """docs/service_config.md's example is a valid config file naming every key (a commissioning engineer
    found no reference for the keys)."""
    import re
    import tomllib

    from bridge.service.config import _TOML_SECTIONS, _flatten_toml

    doc = (Path(__file__).resolve().parents[3] / "docs" / "service_config.md").read_text()
    block = re.search(r"```toml\n(.*?)```", doc, re.DOTALL)
    assert block is not None
    data = tomllib.loads(block.group(1))
    flat = _flatten_toml(data, "docs/service_config.md")  # every section and key known
    assert {s: set(v) for s, v in data.items()} == {s: set(v) for s, v in _TOML_SECTIONS.items()}
    # and its values go together (a review: simulate_ecu = true with hitch_status_address = 240 is refused at
    # start); the files it names do not exist here
    files = ("security", "sim_truth", "lines_file", "can_log", "data_dir", "profile", "sim_field")
    ServiceConfig(**{k: v for k, v in flat.items() if k not in files})


def test_a_client_that_reaches_no_router_is_told_what_to_check(tmp_path):
    """A fleet trial: a wrong password (or no router) said only Zenoh's "Unable to connect to any of …"."""
    from bridge.service.server import HitchService, ServiceStartError
    from tests.integration.service_process import free_port

    ep = f"tcp/127.0.0.1:{free_port()}"  # nothing listens there
    cfg = ServiceConfig(mode="client", connect=[ep], data_dir=tmp_path, planning_processes=0, prefix="nobody/hitch")
    with pytest.raises(ServiceStartError) as ei:
        HitchService(cfg).start()
    text = str(ei.value)
    assert f"connect {ep}" in text and "Unable to connect" in text, text
    assert "check that a router listens there, and whether it requires a login or TLS (--security)" in text, text


def test_the_link_lease_is_the_services_and_the_routers_to_set(tmp_path):
    """A review: the 2 s lease (a frozen router noticed within it, not after Zenoh's 10 s) was a constant; a radio
    link with longer gaps braked the hitch with no way to say so. [zenoh] lease_s and hitch router --lease-s."""
    import json

    from bridge.cli.router import router_config
    from bridge.service.server import build_zenoh_config

    def lease_ms(z) -> int:
        return json.loads(z.get_json("transport"))["link"]["tx"]["lease"]

    assert lease_ms(build_zenoh_config(ServiceConfig())) == 2000
    f = tmp_path / "svc.toml"
    f.write_text("[zenoh]\nlease_s = 7.5\n")
    assert lease_ms(build_zenoh_config(load_service_config(f))) == 7500
    assert lease_ms(router_config(["tcp/127.0.0.1:7447"])) == 2000
    assert lease_ms(router_config(["tcp/127.0.0.1:7447"], None, 12.0)) == 12000
