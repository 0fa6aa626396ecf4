"""A fleet: a Zenoh router (the Python package in router mode, its own process) and three services
as Zenoh clients with prefixes ``fleet/tNN/hitch``; one client lists them through their
liveliness tokens (``hitch fleet ls``) and queries each. Peers do not route for other peers,
hence the router. All processes are killed in teardown.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time

import pytest

from bridge.service.client import HitchClient, ServiceError
from tests.integration.service_process import ROOT, ROUTER, ServiceProcess, free_port, hitch

pytestmark = pytest.mark.slow  # several services and a router, each in its own process

PREFIXES = ("fleet/t01/hitch", "fleet/t02/hitch", "fleet/t03/hitch")


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    port = free_port()
    router_ep = f"tcp/127.0.0.1:{port}"
    router = subprocess.Popen([sys.executable, "-c", ROUTER, router_ep], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    services: list[ServiceProcess] = []
    try:
        assert "router ready" in router.stdout.readline()
        for i, prefix in enumerate(PREFIXES):
            services.append(
                ServiceProcess(
                    [
                        "--mode",
                        "client",
                        "--connect",
                        router_ep,
                        "--prefix",
                        prefix,
                        "--data-dir",
                        str(tmp_path_factory.mktemp(f"t{i}")),
                        "--implement",
                        "cat2-spreader-400" if i == 0 else "cat2-power-harrow-1500",
                    ]
                )
            )
        yield router_ep, services
    finally:
        for s in services:
            s.kill()
        router.terminate()
        try:
            router.wait(10)
        except subprocess.TimeoutExpired:
            router.kill()


def test_fleet_ls_lists_every_service_and_each_answers(fleet):
    router_ep, services = fleet
    deadline = time.monotonic() + 10
    while True:
        p = hitch(router_ep, "fleet", "ls", "--json")
        assert p.returncode == 0, p.stderr
        rows = json.loads(p.stdout)["fleet"]
        if [r["prefix"] for r in rows] == list(PREFIXES) or time.monotonic() > deadline:
            break
        time.sleep(0.3)
    assert [r["prefix"] for r in rows] == list(PREFIXES)
    assert [r["implement"] for r in rows] == ["cat2-spreader-400", "cat2-power-harrow-1500", "cat2-power-harrow-1500"]
    assert all(r["mode"] == "auto" and r["profile"] == "thesis-t132" for r in rows)
    with HitchClient([router_ep], timeout_s=10.0) as c:
        for prefix in PREFIXES:
            r = c.request("ik", {"x": 0.0, "z": 0.15, "roll": 0.0, "pitch": 0.0}, prefix=prefix)
            assert r["status"] == "ok"
        c.request("presets/save", {"name": "only-t02", "pose": {"z": 0.1}}, prefix="fleet/t02/hitch")
        lists = {p: [x["name"] for x in c.request("presets/list", {}, prefix=p)["presets"]] for p in PREFIXES}
        assert lists == {"fleet/t01/hitch": [], "fleet/t02/hitch": ["only-t02"], "fleet/t03/hitch": []}


def test_fleet_ls_prefix_lists_only_the_services_under_it(fleet):
    """``--prefix`` was accepted and ignored (a fleet trial): ``fleet ls --prefix fleet/t02`` listed all three.
    Now it lists the services whose prefix is that one or has its chunks first; a bad filter is named."""
    router_ep, _ = fleet

    def listed(*flags: str) -> list[str]:
        p = hitch(router_ep, "fleet", "ls", "--json", *flags)
        assert p.returncode == 0, p.stderr
        return [r["prefix"] for r in json.loads(p.stdout)["fleet"]]

    deadline = time.monotonic() + 10
    while listed() != list(PREFIXES) and time.monotonic() < deadline:
        time.sleep(0.3)
    assert listed("--prefix", "fleet") == list(PREFIXES)
    assert listed("--prefix", "fleet/t02") == ["fleet/t02/hitch"]
    assert listed("--prefix", "fleet/t02/hitch") == ["fleet/t02/hitch"]
    assert listed("--prefix", "flee") == []  # chunks, not characters
    p = hitch(router_ep, "fleet", "ls", "--prefix", "fleet/*")
    assert p.returncode != 0 and "fleet/*" in p.stderr and "no wildcards" in p.stderr


def test_a_stopped_service_leaves_the_fleet(fleet):
    router_ep, services = fleet
    services[2].proc.terminate()
    assert services[2].proc.wait(10) == 0
    with HitchClient([router_ep], timeout_s=2.0) as c:
        deadline = time.monotonic() + 10
        while c.fleet() != list(PREFIXES[:2]) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert c.fleet() == list(PREFIXES[:2])
        with pytest.raises(ServiceError) as ei:
            c.request("config", {}, prefix=PREFIXES[2])
        assert ei.value.code == "timeout"
