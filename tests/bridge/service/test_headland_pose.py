"""The quick raise's work pose and the paused work at the headland (``docs/implements.md``, *Quick raise and
return to work*), on the simulated rig in simulated time with the controller's events handed to the implements
logic as the service's event listener does: a raise that starts while the hitch is on its way between work and
the headland (raise pressed twice, raise / stop / raise, a raise during the return) keeps the work pose; a raise
after the operator moved the hitch, or after a return arrived, records a new one; the transport lock forgets
the paused work (field trial findings)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from bridge.service.motion.controller import STOP_GRACE_S
from bridge.service.work import WorkControl
from tests.helpers import SimService, wait_until

PLOW = {"name": "plow", "category": "2", "mass_kg": 1200.0, "com_m": [0.0, 0.6, 0.4]}
HEADLAND = {"x": 0.0, "z": 0.25, "roll": 0.0, "pitch": 0.0}
DOFS = ("x", "z", "roll", "pitch")


class Service(SimService):
    def __init__(self, model, path):
        super().__init__(model, path, prepare=lambda mc: setattr(mc, "work", WorkControl(mc, None)))

    seen = 0  # events handed to the implements logic so far

    def pose(self) -> np.ndarray:
        return self.mc.current_state().position

    def run_forwarding(self, seconds: float) -> None:
        """``run`` with the events handed to ``implements.on_event`` (``HitchService.add_listener``), those of the
        requests since the last run first."""

        def each() -> None:
            new, self.seen = self.events[self.seen :], len(self.events)
            for e in new:
                self.api.implements.on_event(e)

        self.run(seconds, each)

    def last_work_z(self) -> float:
        return self.store.get_implement("plow").last_work["z"]


@pytest.fixture
def svc(model, tmp_path):
    s = Service(model, tmp_path / "hitch.sqlite3")
    yield s
    s.close()


def _at_work(s: Service, z: float = -0.05) -> np.ndarray:
    s.ok("implements/define", {**PLOW, "headland": HEADLAND})
    s.ok("implements/select", {"name": "plow"})
    s.ok("goto", {"goal": {"z": z}})
    s.run_forwarding(5.0)
    assert s.pose()[1] == pytest.approx(z, abs=1e-3)
    return s.pose().copy()


def test_raise_pressed_again_on_the_way_up_keeps_the_work_pose(svc):
    """The field trial: raise, a moment later raise again; last_work.z went from -0.049 to 0.118 and the return
    stopped far above working depth."""
    work = _at_work(svc)
    r = svc.ok("hitch/raise")
    svc.run_forwarding(0.8)
    assert work[1] + 5e-3 < svc.pose()[1] < HEADLAND["z"] - 5e-3  # on its way up, not at the headland
    again = svc.ok("hitch/raise")
    assert again["last_work"]["z"] == pytest.approx(work[1], abs=1e-3) and again["last_work_kept"], again
    svc.run_forwarding(again["duration"] + r["duration"] + 0.5)
    assert svc.last_work_z() == pytest.approx(work[1], abs=1e-3)
    back = svc.ok("hitch/return")
    svc.run_forwarding(back["duration"] + 0.5)
    np.testing.assert_allclose(svc.pose(), work, atol=1e-3)


def test_raise_stop_raise_keeps_the_work_pose_from_before_the_first_raise(svc):
    work = _at_work(svc, -0.1)
    svc.ok("hitch/raise")
    svc.run_forwarding(0.5)
    svc.ok("stop")
    svc.run_forwarding(1.5)
    assert work[1] + 5e-3 < svc.pose()[1] < HEADLAND["z"] - 5e-3  # stopped partway up
    time.sleep(STOP_GRACE_S + 0.02)  # a request just after a stop may have been sent before it: refused
    r = svc.ok("hitch/raise")
    svc.run_forwarding(r["duration"] + 0.5)
    assert svc.last_work_z() == pytest.approx(-0.1, abs=1e-3)


def test_a_raise_during_an_unfinished_return_keeps_the_work_pose(svc):
    work = _at_work(svc)
    r = svc.ok("hitch/raise")
    svc.run_forwarding(r["duration"] + 0.5)
    svc.ok("hitch/return")
    svc.run_forwarding(0.5)
    assert work[1] + 5e-3 < svc.pose()[1] < HEADLAND["z"] - 5e-3  # on its way down
    r = svc.ok("hitch/raise")  # the operator changed their mind: up again
    svc.run_forwarding(r["duration"] + 0.5)
    assert svc.last_work_z() == pytest.approx(work[1], abs=1e-3)


def test_a_raise_after_the_operator_moved_the_hitch_or_a_return_arrived_records_the_new_work_pose(svc):
    _at_work(svc)
    r = svc.ok("hitch/raise")
    svc.run_forwarding(r["duration"] + 0.5)
    svc.ok("goto", {"goal": {"z": 0.0}})  # the operator sets another depth from the headland
    svc.run_forwarding(5.0)
    r = svc.ok("hitch/raise")
    assert "last_work_kept" not in r and r["last_work"]["z"] == pytest.approx(0.0, abs=1e-3), r
    svc.run_forwarding(r["duration"] + 0.5)
    assert svc.last_work_z() == pytest.approx(0.0, abs=1e-3)
    svc.ok("goto", {"goal": {"z": 0.1}})  # moved partway up by the operator, then raised: that is work
    svc.run_forwarding(0.4)
    moving_z = svc.pose()[1]
    r = svc.ok("hitch/raise")
    assert r["last_work"]["z"] == pytest.approx(moving_z, abs=1e-3), r
    svc.run_forwarding(r["duration"] + 0.5)
    back = svc.ok("hitch/return")
    svc.run_forwarding(back["duration"] + 0.5)
    here = svc.pose().copy()
    r = svc.ok("hitch/raise")  # after a return that arrived: a work position
    assert "last_work_kept" not in r and r["last_work"]["z"] == pytest.approx(here[1], abs=1e-3), r


def test_the_transport_lock_forgets_the_paused_work(svc):
    """The field trial: at the headland after a raise at work, lock and unlock; the return started the old work
    session again. The lock means road transport: the return after it only goes back."""
    svc.ok("implements/define", {**PLOW, "headland": HEADLAND})
    svc.ok("implements/select", {"name": "plow"})
    svc.ok("work/settings", {"mode": "position"})
    svc.ok("work/start", {"z": 0.1})
    svc.run_forwarding(3.0)
    session = svc.states[-1]["work"]["session"]
    r = svc.ok("hitch/raise")
    assert r["work_paused"]["session"] == session, r
    svc.run_forwarding(r["duration"] + 1.0)
    locked = svc.ok("implements/lock")
    assert locked["transport_locked"] and locked["work_paused_cleared"]["session"] == session, locked
    assert svc.api.implements.paused_work is None
    assert "work_paused_cleared" not in svc.ok("implements/unlock")
    r = svc.ok("hitch/return")
    assert "resumes_work" not in r, r
    svc.run_forwarding(r["duration"] + 1.0)
    assert svc.pose()[1] == pytest.approx(0.1, abs=3e-3)  # back to the work pose all the same
    assert not wait_until(lambda: any(e["event"] == "work_resumed" for e in svc.events), timeout_s=0.5)
    svc.run_forwarding(0.5)
    assert not svc.states[-1]["work"]["running"]


def test_a_raise_after_the_operator_jogged_from_a_stopped_raise_records_the_jogged_pose(svc):
    """Raise, stop partway, the operator jogs down to a new depth: that is a work position (a stop is not)."""
    _at_work(svc)
    svc.ok("hitch/raise")
    svc.run_forwarding(0.8)
    svc.ok("stop")
    svc.run_forwarding(1.5)
    time.sleep(STOP_GRACE_S + 0.02)
    svc.ok("jog", {"vz": -0.02, "ttl_ms": 1000})
    svc.run_forwarding(2.0)
    jogged = svc.pose()[1]
    r = svc.ok("hitch/raise")
    assert "last_work_kept" not in r and r["last_work"]["z"] == pytest.approx(jogged, abs=1e-3), r
    svc.run_forwarding(r["duration"] + 0.5)
    assert svc.last_work_z() == pytest.approx(jogged, abs=1e-3)


def test_a_teach_in_records_the_raise_and_the_return_as_gotos_to_their_poses(svc):
    """A field trial: record start; return; raise; goto z=0.2; record stop gave a script of the goto alone:
    the raise and the return were left out without a word. They are recorded as the gotos they are."""
    import yaml

    work = _at_work(svc)
    up = svc.ok("hitch/raise")
    svc.run_forwarding(up["duration"] + 0.5)
    assert svc.ok("maneuvers/record/start")
    back = svc.ok("hitch/return")
    svc.run_forwarding(back["duration"] + 0.5)
    up = svc.ok("hitch/raise", {"speed_scale": 0.5})
    svc.run_forwarding(up["duration"] + 0.5)
    svc.ok("goto", {"goal": {"z": 0.2}})
    svc.run_forwarding(3.0)
    script = yaml.safe_load(svc.ok("maneuvers/record/stop")["script"])
    gotos = [s["goto"] for s in script["steps"] if "goto" in s]
    assert len(gotos) == 3, script
    assert gotos[0]["z"] == pytest.approx(work[1], abs=1e-3) and "speed_scale" not in gotos[0]  # the return
    assert gotos[1] == {**HEADLAND, "speed_scale": 0.5}  # the raise, at its speed
    assert gotos[2] == {"z": 0.2}
