"""PeriodicThread (bridge/service/periodic.py) on a simulated clock: absolute deadlines, a late
cycle that does not shift the later ones, and the re-anchoring after several late cycles in a row."""

from __future__ import annotations

import pytest

from bridge.service.periodic import PeriodicThread


class SimClock:
    def __init__(self) -> None:
        self.t = 100.0

    def monotonic(self) -> float:
        return self.t


class SimStop:
    """The thread's stop event: ``wait`` lets the simulated time pass instead of sleeping."""

    def __init__(self, clock: SimClock) -> None:
        self.clock, self.flag = clock, False

    def is_set(self) -> bool:
        return self.flag

    def wait(self, delay: float) -> bool:
        self.clock.t += delay
        return self.flag

    def set(self) -> None:
        self.flag = True


def run(n: int, on_cycle) -> tuple[list[float], PeriodicThread]:
    clock = SimClock()
    starts: list[float] = []

    def fn() -> None:
        starts.append(clock.t - 100.0)
        on_cycle(len(starts), th, clock)
        if len(starts) == n:
            th._stop.set()

    th = PeriodicThread(0.02, fn, name="test", clock=clock.monotonic)
    th._stop = SimStop(clock)  # type: ignore[assignment]
    th._run()
    return starts, th


def test_cycles_start_on_absolute_deadlines():
    starts, th = run(5, lambda k, th, clock: setattr(clock, "t", clock.t + 0.003))  # 3 ms of work
    assert starts == pytest.approx([0.02, 0.04, 0.06, 0.08, 0.10])
    assert th.overruns == 0


def test_a_late_cycle_does_not_shift_the_later_deadlines():
    def on_cycle(k, th, clock):
        if k == 2:
            clock.t += 0.025  # one cycle's work overruns its period

    starts, th = run(5, on_cycle)
    assert starts == pytest.approx([0.02, 0.04, 0.065, 0.08, 0.10])
    assert th.overruns == 1


def test_after_three_late_cycles_in_a_row_the_schedule_is_re_anchored_not_caught_up():
    def on_cycle(k, th, clock):
        if k in (2, 3, 4):
            clock.t += 0.03  # three cycles in a row overrun their period

    starts, th = run(8, on_cycle)
    # cycles 3, 4 and 5 start late (0.07, 0.10, 0.13); the third late one re-anchors the schedule at its
    # start, so the next deadlines are 0.15, 0.17, … (no burst of cycles to catch up the lost 0.06 s)
    assert starts == pytest.approx([0.02, 0.04, 0.07, 0.10, 0.13, 0.15, 0.17, 0.19])
    assert th.overruns == 3
