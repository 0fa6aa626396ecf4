"""Helpers shared by tests (import as ``from tests.helpers import …``)."""

from __future__ import annotations

import contextlib
import importlib
import json
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest

from planner.errors import HitchInputError
from planner.model.kinematics import HitchModel
from planner.model.types import KinematicsError

__all__ = [
    "SimService",
    "bridge_modules_after",
    "check_facade_errors",
    "check_facade_names",
    "goto_when_ready",
    "profile_file_with_final_approach",
    "running_machine",
    "random_closing_actuators",
    "wait_until",
]


def random_closing_actuators(model: HitchModel, rng: np.random.Generator, n: int) -> list[np.ndarray]:
    """Random actuator vectors uniformly inside the strokes for which the mechanism closes."""
    out = []
    while len(out) < n:
        q = model.lower + (model.upper - model.lower) * rng.random(5)
        try:
            model.forward(q)
        except KinematicsError:
            continue
        out.append(q)
    return out


#: the count approach of the nominal twin's ECU, as ``hitch sim stop-offsets`` measures it (the bench's
#: ``twin_count_approach``, rounded): where a piston stops inside its count after a back-off of 1, 2, 3 counts
TWIN_COUNT_APPROACH = """
[motion.count_approach.from_below_counts]
lift = [0.193, 0.305, 0.426]
tilt = [-0.0887, -0.0869, -0.0843]
top = [-0.1241, -0.1231, -0.1194]
left = [-0.1147, -0.1115]
right = [-0.1125, -0.1087]

[motion.count_approach.from_above_counts]
lift = [-0.1956, -0.3058, -0.4516]
tilt = [0.0830]
top = [0.1161, 0.1078]
left = [0.0643]
right = [0.1138]
"""


def profile_file_with_final_approach(
    directory: Path, name: str = "with-approach.toml", *, count_approach: bool = False
) -> Path:
    """The built-in thesis profile written to ``directory`` with a final approach of 2.5 mm, 4 mm, 5 mrad and
    7 mrad (``[motion.final_approach]``), as an operator would add it; ``count_approach``: also the nominal twin's
    count approach (:data:`TWIN_COUNT_APPROACH`)."""
    import planner.profiles

    text = (Path(planner.profiles.__file__).parent / "thesis-t132.toml").read_text(encoding="utf-8")
    path = directory / name
    text += "\n[motion.final_approach]\nx = 0.0025\nz = 0.004\nroll = 0.005\npitch = 0.007\n"
    path.write_text(text + (TWIN_COUNT_APPROACH if count_approach else ""))
    return path


def profiles_with_own_tractor(root: Path) -> Path:
    """``root/prof/mine.toml``: the built-in thesis profile naming its tractor by the relative path
    ``"my-tractor.toml"`` (a copy of the built-in tractor beside it), and an empty ``root/out`` folder, as an
    implement engineer lays out a profile of their own; the profile's path."""
    import planner.profiles

    builtin = Path(planner.profiles.__file__).parent
    (root / "prof").mkdir()
    (root / "out").mkdir()
    (root / "prof" / "my-tractor.toml").write_text((builtin / "tractors" / "tractor-6t.toml").read_text())
    lines = [
        'tractor_profile = "my-tractor.toml"' if ln.startswith("tractor_profile") else ln
        for ln in (builtin / "thesis-t132.toml").read_text().splitlines()
    ]
    assert 'tractor_profile = "my-tractor.toml"' in lines
    (root / "prof" / "mine.toml").write_text("\n".join(lines) + "\n")
    return root / "prof" / "mine.toml"


def check_facade_names(package: ModuleType) -> None:
    """Every public name of a lazy package facade is listed once and is its defining module's object."""
    sources = package._SOURCES
    assert len(set(package.__all__)) == len(package.__all__) == len(sources)
    for name in package.__all__:
        module = importlib.import_module(sources[name])
        assert name in module.__all__, (name, module.__name__)
        assert getattr(package, name) is getattr(module, name), name
    assert set(dir(package)) >= set(package.__all__)
    with pytest.raises(AttributeError, match="no attribute 'nothing_here'"):
        package.nothing_here  # noqa: B018


def check_facade_errors(package: ModuleType) -> None:
    """Every public exception of a package is a HitchInputError (there is at least one)."""
    errors = [
        n
        for n in package.__all__
        if isinstance(getattr(package, n), type) and issubclass(getattr(package, n), Exception)
    ]
    assert errors
    for name in errors:
        assert issubclass(getattr(package, name), HitchInputError), name


def bridge_modules_after(statement: str) -> set[str]:
    """The ``bridge`` modules a fresh interpreter has loaded after ``statement``."""
    code = f"import sys; {statement}; print(' '.join(m for m in sys.modules if m.startswith('bridge')))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    return set(out.split())


def wait_until(pred: Callable[[], Any], timeout_s: float = 20.0, period_s: float = 0.02) -> bool:
    """Poll ``pred`` every ``period_s`` (wall clock) until it is truthy (True) or ``timeout_s`` ran out (False)."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(period_s)
    return False


def goto_when_ready(mc: Any, goal: dict[str, float], speed_scale: float = 1.0, timeout_s: float = 10.0) -> bool:
    """Send ``mc.goto(goal)`` as soon as the controller can take it (its link claimed, a first measurement
    in): True once sent, False if it was still refused after ``timeout_s``."""
    from bridge.service.motion.types import MotionError

    def sent() -> bool:
        try:
            mc.goto(goal, speed_scale=speed_scale)
        except MotionError:  # not claimed / no measurement yet
            return False
        return True

    return wait_until(sent, timeout_s)


@contextlib.contextmanager
def running_machine(channel_prefix: str) -> Iterator[tuple[Any, Any, Any, list[dict[str, Any]]]]:
    """The machine side as a service builds it (``start_can`` with the twin on a fresh virtual channel) and
    its started motion controller: ``(cfg, parts, controller, events)``, the controller's events collected
    in ``events``; closed (controller, then parts) on exit."""
    import tempfile
    import uuid

    from bridge.service.config import ServiceConfig
    from bridge.service.machine import build_controller, start_can

    cfg = ServiceConfig(data_dir=tempfile.mkdtemp(), can_channel=f"{channel_prefix}-{uuid.uuid4().hex}")
    parts = start_can(cfg)
    events: list[dict[str, Any]] = []
    try:
        mc, _ = build_controller(cfg, parts, on_state=lambda m: None, on_event=events.append)
        mc.start()
        try:
            yield cfg, parts, mc, events
        finally:
            mc.close()
    finally:
        parts.close()


class SimService:
    """A :class:`~bridge.service.motion.controller.MotionController` and its
    :class:`~bridge.service.api.ServiceAPI` on a simulated CAN rig (real CAN path, simulated time),
    planning inline, the control cycles driven by the test every :attr:`DT` of simulated time.

    ``settle_s`` None: one cycle before the store and the API are made; a number: that long run
    after them. ``prepare(mc)`` runs before either (e.g. to give the controller its work control);
    ``api_options`` go to the ``ServiceAPI`` (``planning``, ``policy``, ``sim_fault`` …)."""

    DT = 0.02

    def __init__(
        self,
        model: Any,
        store_path: Path,
        *,
        ik: Any = None,
        plan_guard: Any = None,
        prepare: Callable[[Any], None] | None = None,
        settle_s: float | None = None,
        **api_options: Any,
    ):
        from bridge.service.api import ServiceAPI
        from bridge.service.motion.controller import MotionController
        from bridge.service.store import HitchStore
        from bridge.sim.move import SimRig
        from planner.limits.guard import Guard
        from planner.trajectory import TrajectoryPlanner

        self.model = model
        self.rig = SimRig(model)
        self.rig.start()
        self.rig.run_until(0.5)
        self.events: list[dict] = []
        #: called with each event as it is delivered (after it is in ``events``): what a client does on it
        self.event_listeners: list[Callable[[dict], None]] = []
        self.states: list[dict] = []
        self.mc = MotionController(
            Guard(TrajectoryPlanner(model)),
            plan_guard or Guard(TrajectoryPlanner(model)),
            self.rig.link,
            lambda: self.rig.now_s,
            on_event=self._deliver,
            on_state=self.states.append,
            spawn=lambda fn: fn(),
        )
        if prepare is not None:
            prepare(self.mc)
        if settle_s is None:
            self.mc.cycle()
        self.store = HitchStore(store_path)
        self.api = ServiceAPI(self.mc, ik, self.store, {"profile": "thesis-t132"}, **api_options)
        if settle_s is not None:
            self.run(settle_s)

    def _deliver(self, event: dict) -> None:
        self.events.append(event)
        for listener in list(self.event_listeners):
            listener(event)

    def call(self, key: str, payload: Any = None, user: str | None = None, **kw: Any) -> tuple[bool, dict]:
        """``api.handle``; ``payload`` a mapping (sent as JSON; None: ``{}``) or raw bytes / text."""
        data = payload if isinstance(payload, (bytes, str)) else json.dumps(payload if payload is not None else {})
        return self.api.handle(key, data, user, **kw)

    def ok(self, key: str, payload: Any = None) -> dict:
        """``call`` that must succeed; its reply."""
        ok, r = self.call(key, payload)
        assert ok, (key, r)
        return r

    def run(self, seconds: float, each: Callable[[], None] | None = None) -> None:
        """Run the rig and the control cycle for ``seconds`` of simulated time (``each()`` before every step)."""
        end = self.rig.now_s + seconds
        while self.rig.now_s < end - 1e-9:
            if each is not None:
                each()
            self.rig.run_until(self.rig.now_s + self.DT)
            self.mc.cycle()

    def close(self) -> None:
        self.store.close()
        self.rig.close()


def loopback_zenoh_config(mode: str, endpoint: str) -> Any:
    """A Zenoh config that listens on ``endpoint`` (a ``tcp/127.0.0.1:…`` address) in ``mode`` (``peer`` or
    ``router``), multicast scouting off: nothing leaves loopback."""
    import zenoh  # only the tests that open sessions load it

    cfg = zenoh.Config()
    cfg.insert_json5("mode", json.dumps(mode))
    cfg.insert_json5("listen/endpoints", json.dumps([endpoint]))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    return cfg


def loopback_client_session(endpoint: str) -> Any:
    """A Zenoh session in client mode connected to ``endpoint`` (``tcp/127.0.0.1:…``), multicast scouting off;
    the caller closes it."""
    import zenoh

    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"client"')
    cfg.insert_json5("connect/endpoints", json.dumps([endpoint]))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(cfg)


class Gate:
    """Holds calls of a function until opened: ``held = Gate(fn)``; every call of ``held`` first counts
    itself (``entered``, one release per call) and then waits until :meth:`open` (at most ``wait_s``)."""

    def __init__(self, fn: Callable, wait_s: float = 10.0) -> None:
        import threading

        self.fn, self.wait_s = fn, wait_s
        self.opened, self.entered = threading.Event(), threading.Semaphore(0)

    def __call__(self, *a, **k):
        self.entered.release()
        self.opened.wait(self.wait_s)
        return self.fn(*a, **k)

    def open(self) -> None:
        self.opened.set()
