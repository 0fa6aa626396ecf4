"""``hitch maneuver record start|stop [--save]``, ``hitch maneuver pause|resume|skip`` and ``hitch lines
save|list|delete`` against a running service (the control core in its own process, the default)."""

from __future__ import annotations

import json
import time

import pytest

from bridge.cli.main import main
from bridge.service.client import HitchClient
from bridge.service.config import ServiceConfig
from bridge.service.gnss import LocalTangentPlane
from bridge.service.server import HitchService
from tests.helpers import wait_until
from tests.integration.service_process import free_port

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def service(tmp_path_factory):
    ep = f"tcp/127.0.0.1:{free_port()}"
    cfg = ServiceConfig(listen=[ep], data_dir=tmp_path_factory.mktemp("svc"), planning_processes=1)
    svc = HitchService(cfg).start()
    try:
        assert wait_until(lambda: (svc.latest_state or {}).get("ecu", {}).get("online")), "no state from the core"
        yield svc, ep
    finally:
        svc.close()


def _cli(capsys, ep, *argv: str) -> tuple[int, str, str]:
    rc = main([*argv, "--connect", ep, "--timeout", "10"])
    out = capsys.readouterr()
    return rc, out.out, out.err


def test_lines_save_list_delete(service, capsys, tmp_path):
    svc, ep = service
    plane = LocalTangentPlane(48.0, 11.0)
    a, b = plane.to_geodetic(20.0, -50.0), plane.to_geodetic(20.0, 50.0)
    f = tmp_path / "headland.geojson"
    f.write_text(json.dumps({"type": "LineString", "coordinates": [[a[1], a[0]], [b[1], b[0]]]}))
    rc, out, err = _cli(capsys, ep, "lines", "save", "headland", str(f))
    assert rc == 0 and "saved headland" in out, err
    rc, out, _ = _cli(capsys, ep, "lines", "list", "--json")
    assert rc == 0 and [ln["name"] for ln in json.loads(out)["lines"]] == ["headland"]
    rc, out, _ = _cli(capsys, ep, "lines", "list")
    assert rc == 0 and "headland: 2 vertices, crossed 0 time(s)" in out
    bad = tmp_path / "bad.geojson"
    bad.write_text(json.dumps({"type": "LineString", "coordinates": [[11.0, 48.0], [11.0, 95.0]]}))
    rc, out, err = _cli(capsys, ep, "lines", "save", "bad", str(bad))
    assert rc != 0 and "lat" in err and "[-85, 85]" in err, err
    rc, _, err = _cli(capsys, ep, "lines", "save", "x", str(tmp_path / "missing.geojson"))
    assert rc == 2 and "does not exist" in err
    rc, _, err = _cli(capsys, ep, "lines", "save", "headland", str(f))  # saved already: not replaced unasked
    assert rc != 0 and "saved already" in err and "--replace" in err, err
    rc, out, err = _cli(capsys, ep, "lines", "save", "headland", str(f), "--replace")
    assert rc == 0 and "saved headland (replaced headland)" in out, err
    lift = tmp_path / "lift.yaml"  # a saved maneuver waits for the line: delete needs --force
    lift.write_text("steps:\n  - wait_for: {line: headland}\n  - goto: {z: 0.2}\n")
    rc, _, err = _cli(capsys, ep, "maneuver", "save", "lift", str(lift))
    assert rc == 0, err
    rc, _, err = _cli(capsys, ep, "lines", "delete", "headland")
    assert rc != 0 and "waited for by the saved maneuver(s) lift" in err and "--force" in err, err
    rc, out, _ = _cli(capsys, ep, "lines", "delete", "headland", "--force")
    assert rc == 0 and "deleted headland (warning: line 'headland' was waited for by lift)" in out
    assert _cli(capsys, ep, "maneuver", "delete", "lift")[0] == 0
    rc, _, err = _cli(capsys, ep, "lines", "delete", "headland")
    assert rc != 0 and ("not_found" in err or "no line" in err), err


def test_pause_resume_skip_and_record_through_the_cli(service, capsys, tmp_path):
    svc, ep = service
    with HitchClient([ep], timeout_s=10) as c:
        c.wait_motion(c.goto({"z": 0.0})["motion_id"], timeout_s=20)
        c.request(
            "maneuvers/save",
            {"name": "m", "script": "steps:\n  - goto: {z: 0.3, speed_scale: 0.4}\n  - wait: 30\n"},
        )
    rc, _, err = _cli(capsys, ep, "maneuver", "pause")
    assert rc != 0 and "no maneuver is running" in err, err
    rc, out, err = _cli(capsys, ep, "maneuver", "run", "m")
    assert rc == 0, err
    assert wait_until(lambda: svc.latest_state["pose"]["z"] > 0.03, 10.0)
    rc, out, err = _cli(capsys, ep, "maneuver", "pause")
    assert rc == 0 and "paused, step 1 (index 0)" in out, (out, err)
    assert wait_until(lambda: not svc.latest_state["moving"], 5.0)
    assert svc.latest_state["maneuver"]["paused"] is True
    rc, out, _ = _cli(capsys, ep, "maneuver", "resume", "--json")
    assert rc == 0 and json.loads(out)["maneuver"]["paused"] is False
    assert wait_until(lambda: (svc.latest_state.get("maneuver") or {}).get("step") == 1, 15.0), svc.latest_state.get(
        "maneuver"
    )
    rc, out, _ = _cli(capsys, ep, "maneuver", "skip")
    assert rc == 0 and "skip" in out
    assert wait_until(lambda: svc.latest_state.get("maneuver") is None, 5.0)

    rc, out, err = _cli(capsys, ep, "maneuver", "record", "start")
    assert rc == 0 and "recording" in out, err
    with HitchClient([ep], timeout_s=10) as c:
        c.wait_motion(c.goto({"z": 0.15})["motion_id"], timeout_s=20)
    rc, out, err = _cli(capsys, ep, "maneuver", "record", "stop", "--save", "taught")
    assert rc == 0 and "goto" in out and "saved taught" in out, (out, err)
    rc, out, _ = _cli(capsys, ep, "maneuver", "list")
    assert "taught" in out
    rc, _, err = _cli(capsys, ep, "maneuver", "record", "stop")
    assert rc != 0 and "no recording" in err, err


def test_a_geojson_path_that_is_no_file_says_so(tmp_path):
    """A field operator's report: `hitch lines save l1 /dev/null` said "does not exist"."""
    from bridge.cli.errors import CLIError
    from bridge.cli.headland import _read_geojson

    with pytest.raises(CLIError, match="is not a regular file"):
        _read_geojson("/dev/null")
    with pytest.raises(CLIError, match="does not exist"):
        _read_geojson(str(tmp_path / "nope.geojson"))
    f = tmp_path / "bom.geojson"  # a byte-order mark, as Windows editors write
    f.write_bytes(b"\xef\xbb\xbf" + json.dumps({"type": "LineString", "coordinates": [[11, 48], [11, 48.1]]}).encode())
    assert _read_geojson(str(f))["type"] == "LineString"


def test_a_client_waits_for_a_maneuver_by_the_id_its_run_reply_gives(service, capsys):
    """``maneuvers/run`` answered ``motion_id``, the maneuver's id, which no motion carries: a fleet client's
    ``wait_motion`` on it returned at once while the steps ran as motions of their own. The reply names it
    ``maneuver_id`` now, and ``wait_maneuver`` waits for the maneuver's outcome."""
    svc, ep = service
    with HitchClient([ep], timeout_s=10) as c:
        c.request("maneuvers/save", {"name": "two", "script": "steps:\n  - goto: {z: 0.05}\n  - goto: {z: 0.08}\n"})
        r = c.request("maneuvers/run", {"name": "two"})
        out = c.wait_maneuver(r["maneuver_id"], timeout_s=30)
        assert out["outcome"]["event"] == "maneuver_finished" and out["outcome"]["maneuver_id"] == r["maneuver_id"]
        assert abs(out["state"]["pose"]["z"] - 0.08) < 3e-3
    rc, out_text, err = _cli(capsys, ep, "maneuver", "run", "two", "--wait")
    assert rc == 0 and "finished" in out_text, (out_text, err)


def test_a_wait_for_a_maneuver_that_ended_before_it_began_gives_its_outcome(service):
    """A fleet trial: run a maneuver, stop it, then ``wait_maneuver``: no outcome, though the service kept the
    ``maneuver_aborted`` event (``events/recent``). Truth: the event the subscription heard while it happened."""
    svc, ep = service
    with HitchClient([ep], timeout_s=10) as c:
        heard: list[dict] = []
        sub = c.subscribe("events", heard.append)
        c.request("maneuvers/save", {"name": "long", "script": "steps:\n  - goto: {z: 0.02}\n  - goto: {z: 0.2}\n"})
        r = c.request("maneuvers/run", {"name": "long"})
        mid = r["maneuver_id"]
        c.stop()
        assert wait_until(lambda: any(e.get("maneuver_id") == mid and e["event"] == "maneuver_aborted" for e in heard))
        sub.close()
        t0 = time.monotonic()
        out = c.wait_maneuver(mid, timeout_s=30)
        took = time.monotonic() - t0
        want = next(e for e in heard if e.get("maneuver_id") == mid and e["event"] == "maneuver_aborted")
        assert out.get("outcome") == want, out
        assert "state" in out and took < 2.0, took  # not the 2 s a wait gives a maneuver it never saw
        # the run's id in the reply: a wait for that run finds it; one for another run (a restarted service
        # numbers its maneuvers from 1 again: a review) does not take this run's event for its outcome
        assert r.get("instance") and c.wait_maneuver(mid, timeout_s=30, instance=r["instance"])["outcome"] == want
        assert "outcome" not in c.wait_maneuver(mid, timeout_s=30, instance="another-run")
