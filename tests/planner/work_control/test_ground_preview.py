"""The ground preview (planner.work_control.ground_preview) on constructed ground: a bump, a step, a grade,
the rolling ground of the ``terrain`` scenario with sensor noise. The truth is geometry computed here: the
ground under the tool above the straight line through the two axles' contact points (the tractor's
contact plane, level across), evaluated where the tractor will be, never the preview's own fit."""

from __future__ import annotations

import math

import numpy as np
import pytest

from planner.work_control.ground_preview import GroundPreview, GroundPreviewError, PreviewGeometry

L, F, D = 2.7, 3.7, 1.2  # wheelbase, preview sensor ahead of the rear axle, tool behind it [m]
STEP = 2.2222 * 0.02  # 8 km/h, 50 Hz


def truth(h, s):
    """The ground's height at the tool (D behind the rear axle at s) above the line through (s, h(s)) and
    (s + L, h(s + L)): the contact plane of a tractor on rigid axles, level across."""
    rear, front = h(s), h(s + L)
    line_at_tool = rear + (front - rear) * (-D) / L
    return h(s - D) - line_at_tool


def above_line(h, s, x):
    rear, front = h(s), h(s + L)
    return h(s + x) - (rear + (front - rear) * x / L)


def drive(h, n, *, noise=0.0, seed=0, tool=True, preview=None):
    """Feed the preview n readings of ground ``h`` (m) every STEP metres; yields (preview, s)."""
    gp = preview if preview is not None else GroundPreview(PreviewGeometry(L, F, D))
    rng = np.random.default_rng(seed)
    for k in range(n):
        s = k * STEP
        pitch = math.atan((h(s + L) - h(s)) / L) + float(rng.normal(0.0, noise / 10.0)) if noise else 0.0
        if not noise:
            pitch = math.atan((h(s + L) - h(s)) / L)
        ahead = above_line(h, s, F) + (float(rng.normal(0.0, noise)) if noise else 0.0)
        at_tool = truth(h, s) + (float(rng.normal(0.0, noise)) if noise else 0.0)
        gp.add(s, pitch, ahead, at_tool if tool else None)
        yield gp, s


def bump(x0=10.0, width=1.5, height=0.04):
    def h(x):
        u = (x - x0) / width
        return height * 0.5 * (1.0 + math.cos(math.pi * u)) if abs(u) < 1.0 else 0.0

    return h


def test_a_bump_is_previewed_where_the_tool_will_meet_it_by_distance():
    """A 40 mm bump at 10 m: the tool meets it at s = 10 + D; the preview shows it there (F - L ahead of the
    current distance) as soon as the front sensor has passed it, and matches the geometry within 1.5 mm."""
    h = bump()
    preview = PreviewGeometry(L, F, D).preview_m
    assert preview == pytest.approx(F - L)
    worst, seen_peak_at, true_peak_at = 0.0, None, None
    best = true_best = -1.0
    for gp, s in drive(h, 500):
        ahead = s + preview
        if not gp.ready(ahead):
            continue
        est, tru = gp.ground_at_tool(ahead), truth(h, ahead)
        worst = max(worst, abs(est - tru))
        if est > best:
            best, seen_peak_at = est, ahead
        if tru > true_best:
            true_best, true_peak_at = tru, ahead
    assert worst < 0.0015
    # the tool point s - D crosses the bump's top at s = 10 + D (the rear axle, on the bump's far flank then,
    # lifts the plane a little, so the truth peaks a few cm later); the preview's peak lies there
    assert true_peak_at == pytest.approx(10.0 + D, abs=0.3)
    assert seen_peak_at == pytest.approx(true_peak_at, abs=0.1)
    assert best == pytest.approx(true_best, abs=0.0015)


def test_the_preview_is_ready_only_after_the_front_sensor_has_seen_the_ground_under_the_tool():
    """The delay in distance: the ground under the tool at s' was seen by the front sensor at s' - D - F;
    with readings from s = 0 on, the first ready distance is D + F (not earlier), and at most F - L ahead."""
    h = bump()
    first = None
    for gp, s in drive(h, 200, tool=False):
        if first is None and gp.ready(s):
            first = s
    assert first is not None and D + F - STEP <= first <= D + F + STEP
    with pytest.raises(GroundPreviewError, match="outside the preview"):
        gp.ground_at_tool(s + (F - L) + 0.1)


def test_a_step_and_a_grade():
    """A grade (straight ground) is no ground above the contact plane: 0 everywhere. A 30 mm step (smoothed
    over 0.4 m) is previewed within 3 mm where no wheel nor the tool is within 0.6 m of its edge (at the
    edge the 0.2 m grid rounds the corners)."""
    grade = drive(lambda x: 0.05 * x - 0.3, 400, tool=False)
    for gp, s in grade:
        if gp.ready(s + 0.5):
            assert abs(gp.ground_at_tool(s + 0.5)) < 1e-4

    def step(x):
        return 0.03 * min(1.0, max(0.0, (x - 10.0) / 0.4))

    errors = []
    for gp, s in drive(step, 500):
        at = s + 0.5
        if gp.ready(at) and all(abs(at + o - 10.2) > 0.6 for o in (-D, 0.0, L)):  # away from the edge
            errors.append(abs(gp.ground_at_tool(at) - truth(step, at)))
    assert errors and max(errors) < 0.003


def test_rolling_ground_with_sensor_noise_is_previewed_within_millimetres():
    """The ``terrain`` scenario's ground (30 mm at 7 m + 20 mm at 19 m), 3 mm sensor noise: the preview half a
    metre ahead (0.23 s at 8 km/h) is within 1.5 mm RMS of the geometry, where the current ground is
    ~15 mm RMS off (what the old regulator had to act on)."""

    def h(x):
        return 0.03 * math.sin(2 * math.pi * x / 7.0) + 0.02 * math.sin(2 * math.pi * x / 19.0 + 0.5)

    err, stale = [], []
    for gp, s in drive(h, 2000, noise=0.003):
        if gp.ready(s + 0.5):
            err.append(gp.ground_at_tool(s + 0.5) - truth(h, s + 0.5))
            stale.append(truth(h, s) - truth(h, s + 0.5))
    rms = float(np.sqrt(np.mean(np.square(err))))
    assert rms < 0.0015, rms
    assert float(np.sqrt(np.mean(np.square(stale)))) > 10 * rms


def test_bad_input_is_named_and_a_reversal_resets():
    with pytest.raises(GroundPreviewError, match="sensor_ahead_m"):
        PreviewGeometry(wheelbase_m=2.7, sensor_ahead_m=2.8)
    with pytest.raises(GroundPreviewError, match="cell_m"):
        PreviewGeometry(cell_m=0.0)
    gp = GroundPreview()
    with pytest.raises(GroundPreviewError, match="no readings"):
        gp.ground_at_tool(0.0)
    with pytest.raises(GroundPreviewError, match="pitch_rad"):
        gp.add(0.0, math.nan, 0.0)
    for _ in drive(lambda x: 0.0, 150, preview=gp):
        pass
    assert gp.ready()
    gp.add(1.0, 0.0, 0.0)  # distance went back: the buffer restarts
    assert gp.distance_m == 1.0 and not gp.ready()
