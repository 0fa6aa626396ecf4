"""The service config's number settings take numbers only, named by table and key with the allowed range and
its unit; a config file that is not UTF-8 is refused naming the byte (a fuzz trial: ``stale_timeout_s = true``
ran as 1.0 s, and a binary file raised UnicodeDecodeError)."""

from __future__ import annotations

import typing

import pytest

from bridge.service import config
from bridge.service.config import ServiceConfig, ServiceConfigError, load_service_config


@pytest.mark.parametrize(
    "table, key, allowed",
    [
        ("zenoh", "lease_s", ">= 0.5 and <= 60 s"),
        ("can", "stale_timeout_s", ">= 0.05 and <= 2 s"),
        ("can", "sim_ground_speed", ">= 0 and <= 20 m/s"),
        ("can", "sim_gnss_heading", ">= -6.28319 and <= 6.28319 rad"),
        ("can", "hitch_status_address", ">= 0 and <= 253"),
        ("hitch", "control_rate", ">= 10 and <= 200 Hz"),
        ("hitch", "state_rate", ">= 1 and <= 100 Hz"),
        ("hitch", "following_error_lift_rad", ">= 0.001 and <= 0.5 rad"),
        ("hitch", "following_error_m", ">= 0.0001 and <= 0.2 m"),
        ("hitch", "following_error_lag_s", ">= 0 and <= 5 s"),
        ("hitch", "following_error_s", ">= 0.05 and <= 10 s"),
        ("service", "workers", ">= 1 and <= 32"),
        ("service", "planning_processes", ">= 0 and <= 32"),
        ("service", "can_log_max_mb", ">= 0.1 and <= 100000 MB"),
        ("service", "can_log_keep", ">= 1 and <= 1000"),
        ("service", "max_script_bytes_per_user", ">= 65536 and <= 1.07374e+09 bytes"),
    ],
)
def test_a_boolean_or_text_for_a_number_is_refused_naming_table_key_and_range(tmp_path, table, key, allowed):
    f = tmp_path / "svc.toml"
    extra = "simulate_ecu = false\n" if key == "hitch_status_address" else ""
    f.write_text(f"[{table}]\n{extra}{key} = true\n")
    with pytest.raises(ServiceConfigError) as ei:
        load_service_config(f)
    assert str(ei.value) == (
        f"invalid service config ({f}): {table}.{key} = True: must be a number, got true (a boolean) "
        f"(allowed: {allowed})"
    )
    f.write_text(f'[{table}]\n{extra}{key} = "1"\n')
    with pytest.raises(ServiceConfigError) as ei:
        load_service_config(f)
    assert str(ei.value) == (
        f"invalid service config ({f}): {table}.{key} = '1': must be a number, got the text '1' (a number is "
        f"written without quotes) (allowed: {allowed})"
    )


def test_numbers_still_load_from_the_file_ints_included_and_a_flag_is_named_as_a_field(tmp_path):
    f = tmp_path / "svc.toml"
    f.write_text("[zenoh]\nlease_s = 3\n[can]\nstale_timeout_s = 0.3\nsim_gnss_origin = [48, 11.5]\n")
    cfg = load_service_config(f)
    assert (cfg.lease_s, cfg.stale_timeout_s, cfg.sim_gnss_origin) == (3.0, 0.3, (48.0, 11.5))
    assert ServiceConfig.model_validate_json(cfg.model_dump_json()) == cfg  # the core process reads it back so
    with pytest.raises(ServiceConfigError) as ei:
        load_service_config(f, stale_timeout_s=True)  # a flag's value: named as the field
    assert str(ei.value) == (
        f"invalid service config ({f}): stale_timeout_s = True: must be a number, got true (a boolean) "
        "(allowed: >= 0.05 and <= 2 s)"
    )
    f.write_text("[can]\nsim_gnss_origin = [true, 11.0]\n")
    with pytest.raises(ServiceConfigError) as ei:
        load_service_config(f)
    assert str(ei.value) == (
        f"invalid service config ({f}): can.sim_gnss_origin = [True, 11.0]: must be two numbers (lat, lon in deg), "
        "got true (a boolean)"
    )


def test_every_number_field_refuses_booleans():
    numeric = []
    for name, info in ServiceConfig.model_fields.items():
        args = {a for a in typing.get_args(info.annotation)} | {info.annotation}
        if args & {int, float} or "tuple[" in str(info.annotation) and "float" in str(info.annotation):
            numeric.append(name)
    assert sorted(numeric) == sorted(config.NUMBER_FIELDS)


def test_a_config_that_is_not_utf8_names_the_byte(tmp_path):
    f = tmp_path / "binary.toml"
    f.write_bytes(b"[can]\nchannel = 'h\xf4'\n")
    with pytest.raises(ServiceConfigError) as ei:
        load_service_config(f)
    assert str(ei.value) == f"service config {f}: not UTF-8 text (byte 18, line 2: 0xf4); save it as UTF-8"
