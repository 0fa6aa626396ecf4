"""Sensor calibration over the link against a tape-perturbed twin: each cylinder to both end stops, the
fit recovers the truth's AD map; refusal naming the limit; resumable; the written profile loads."""

import json
import math

import numpy as np
import pytest

from bridge.link.sensor_calibration import (
    EndReading,
    RelayRule,
    SensorCalibration,
    SensorCalibrationError,
    calibration_profile,
    fit_sensor,
    sensor_profile_toml,
)
from bridge.sim.controller import ControllerConfig, build_relay_limits
from bridge.sim.cylinder import build_cylinder_params
from bridge.sim.rig import SimRig, SimSettings
from bridge.sim.truth import MachineTruth, perturb_profile
from planner.limits.tractor import ImplementRecord
from planner.model.kinematics import HitchModel
from planner.profiles.hitch import load_profile, profile_from_dict

FAST = SimSettings(tick_s=0.01)


@pytest.fixture(scope="module")
def free_top_link():
    """The thesis profile with top-link angle limits that let every cylinder travel its full stroke (as with the
    top link unpinned): the thesis's own limits refuse all but the top link (tested below)."""
    data = load_profile("thesis-t132").model_dump(mode="python")
    data["limits"]["top_link_yaw_max"] = 0.5
    data["limits"]["top_link_pitch_up_max"] = 1.2
    return profile_from_dict(data)


def truth_of(profile, seed):
    data, play = perturb_profile(profile, seed)
    return MachineTruth(profile_from_dict(data), play)


def calibrate(nominal, truth, actuators, **kw):
    cal = calibration_profile(nominal, detached=kw.get("detached", False))
    with SimRig(HitchModel(cal), FAST, truth=truth) as rig:
        rig.start()
        rig.run_until(0.5)
        start = rig.ecu.piston_counts().copy()
        try:
            return SensorCalibration(rig.link, rig, nominal, **kw).run(actuators), rig, start
        except SensorCalibrationError as exc:
            return exc, rig, start


def test_the_relay_rule_is_the_ecu_s():
    p = load_profile("thesis-t132")
    for name in ("lift", "tilt", "top", "left", "right"):
        params = build_cylinder_params(name, p.actuator(name))
        lim = build_relay_limits(params, ControllerConfig())
        span = params.counts_max - params.counts_min
        assert lim.low_counts - params.counts_min == RelayRule().margin(span) == params.counts_max - lim.high_counts


def test_the_fit_puts_the_stroke_ends_the_relay_margin_outside_the_readings():
    fit = fit_sensor("tilt", EndReading(35, "relay"), EndReading(899, "relay"))
    # inner span 864 → span 864 + 2m with m = ceil(1 % of it): m = 9 (span 882 → 8.82 → 9)
    assert (fit.counts_min, fit.counts_max, fit.relay_margin_counts) == (26, 908, 9)
    assert fit_sensor("lift", EndReading(5, "relay"), EndReading(20, "relay")).relay_margin_counts == 2
    with pytest.raises(SensorCalibrationError, match="not above"):
        fit_sensor("top", EndReading(50, "relay"), EndReading(40, "relay"))


def test_the_calibration_link_reaches_beyond_the_nominal_ends_on_the_same_map():
    nominal = load_profile("thesis-t132")
    cal = calibration_profile(nominal)
    for name in ("lift", "tilt", "top", "left", "right"):
        n, c = nominal.actuator(name), cal.actuator(name)
        assert c.counts_min < n.counts_min and c.counts_max > n.counts_max and 0 <= c.counts_min
        res_n = (n.max - n.min) / (n.counts_max - n.counts_min)
        res_c = (c.max - c.min) / (c.counts_max - c.counts_min)
        assert res_c == pytest.approx(res_n, rel=1e-12)
        assert c.min == pytest.approx(n.min - (n.counts_min - c.counts_min) * res_n, abs=1e-12)
    lift = cal.actuator("lift")
    assert lift.counts_max - lift.counts_min <= 250  # the rear hitch status resolves whole counts


def test_the_fit_recovers_the_truth_s_counts_within_one_count(free_top_link):
    truth = truth_of(free_top_link, 1)
    fits, _, _ = calibrate(free_top_link, truth, ("lift", "top"))
    assert not isinstance(fits, Exception), fits
    for name, fit in fits.items():
        t = truth.profile.actuator(name)
        assert abs(fit.counts_min - t.counts_min) <= 1 and abs(fit.counts_max - t.counts_max) <= 1, name
        assert fit.low.stopped_by == fit.high.stopped_by == "relay"
    # the truth really differs from the nominal map (else the test proves nothing)
    assert any(
        (truth.profile.actuator(n).counts_min, truth.profile.actuator(n).counts_max)
        != (free_top_link.actuator(n).counts_min, free_top_link.actuator(n).counts_max)
        for n in fits
    )


def test_the_thesis_profile_refuses_a_full_lift_stroke_naming_the_top_link_limit_before_anything_moves():
    nominal = load_profile("thesis-t132")
    exc, rig, start = calibrate(nominal, truth_of(nominal, 1), ("top", "lift"))
    assert isinstance(exc, SensorCalibrationError)
    assert "lift refused: top_link_pitch_max" in str(exc)
    assert "--detached releases the top-link angle limits" in str(exc)  # the way the docs give (it said nothing)
    assert np.array_equal(rig.ecu.piston_counts(), start)  # refused before the top link moved either
    exc, _, _ = calibrate(nominal, truth_of(nominal, 1), ("left",))
    assert "left refused: top_link_yaw_min" in str(exc)


def test_a_heavy_implement_refuses_a_full_lift_stroke_naming_the_stability_measure(free_top_link):
    heavy = ImplementRecord("ballast-block", "2", 3000.0, (0.0, 1.2, 0.3))
    exc, _, _ = calibrate(free_top_link, truth_of(free_top_link, 1), ("lift",), implement=heavy)
    assert isinstance(exc, SensorCalibrationError)
    assert "lift refused: stability" in str(exc) and "below its threshold" in str(exc)


def test_a_calibration_resumes_from_its_progress_file(free_top_link, tmp_path):
    truth = truth_of(free_top_link, 2)
    progress = tmp_path / "progress.json"
    first, _, _ = calibrate(free_top_link, truth, ("top",), progress=progress)
    assert not isinstance(first, Exception), first
    rec = json.loads(progress.read_text())
    assert rec["profile"] == free_top_link.name and set(rec["actuators"]["top"]) == {"low", "high", "fit"}
    # drop the high end: the next run finds only that one (the low end is not visited: no creep below it)
    del rec["actuators"]["top"]["high"], rec["actuators"]["top"]["fit"]
    progress.write_text(json.dumps(rec))
    log: list[str] = []
    again, _, _ = calibrate(free_top_link, truth, ("top",), progress=progress, log=log.append)
    assert not isinstance(again, Exception), again
    assert again["top"] == first["top"]
    assert log[0].startswith(f"resuming from {progress}") and log[0].endswith("keeping top low")
    assert (
        log[1].startswith("top low: recorded") and log[1].endswith("(resumed)") and log[2].startswith("top high: relay")
    )
    t = truth.profile.actuator("top")
    assert abs(again["top"].counts_min - t.counts_min) <= 1 and abs(again["top"].counts_max - t.counts_max) <= 1
    # a progress file of another profile is refused
    rec["profile"] = "another"
    progress.write_text(json.dumps(rec))
    with pytest.raises(SensorCalibrationError, match="is for profile 'another'"):
        with SimRig(HitchModel(calibration_profile(free_top_link)), FAST, truth=truth) as rig:
            SensorCalibration(rig.link, rig, free_top_link, progress=progress)


def test_a_finished_or_partly_fitted_progress_file_resumes(free_top_link, tmp_path):
    # a run writes "fit" beside "low" and "high"; the loader knew only the ends ("bad record top.fit"), so an
    # interrupted calibration could never resume once an actuator was done (a commissioning engineer's report)
    truth = truth_of(free_top_link, 2)
    progress = tmp_path / "progress.json"
    first, _, _ = calibrate(free_top_link, truth, ("top",), progress=progress)
    assert not isinstance(first, Exception), first
    assert "fit" in json.loads(progress.read_text())["actuators"]["top"]
    log: list[str] = []
    again, _, _ = calibrate(free_top_link, truth, ("top",), progress=progress, log=log.append)
    assert not isinstance(again, Exception), again
    assert again["top"] == first["top"] and all(line.endswith("(resumed)") for line in log[1:3])
    rec = json.loads(progress.read_text())
    rec["actuators"]["top"]["fit"]["counts_max"] = 4096  # beyond 10 bits: refused, naming the record
    progress.write_text(json.dumps(rec))
    with pytest.raises(SensorCalibrationError, match=r"bad record top\.fit"):
        with SimRig(HitchModel(calibration_profile(free_top_link)), FAST, truth=truth) as rig:
            SensorCalibration(rig.link, rig, free_top_link, progress=progress)


def test_a_progress_file_of_another_machine_is_refused_and_a_resume_says_what_it_keeps(free_top_link, tmp_path):
    """A commissioning engineer's report: a progress file recorded on one twin (truth seed 3) was reused on
    another (seed 5) without a word, and the profile written got the first machine's AD maps. The file now
    records the machine it was taken on (the ECU's NAME, the twin's truth) and another machine's is refused."""
    first_machine, second_machine = truth_of(free_top_link, 2), truth_of(free_top_link, 3)
    progress = tmp_path / "progress.json"
    done, _, _ = calibrate(free_top_link, first_machine, ("top",), progress=progress, machine="twin A")
    assert not isinstance(done, Exception), done
    rec = json.loads(progress.read_text())
    assert rec["machine"] == "twin A" and rec["saved"]
    log: list[str] = []
    other, _, _ = calibrate(
        free_top_link, second_machine, ("top",), progress=progress, machine="twin B", log=log.append
    )
    assert isinstance(other, SensorCalibrationError)
    assert "was recorded on twin A, not on twin B" in str(other) and "another --progress" in str(other)
    # a machine that cannot be named (its ECU's NAME unheard) cannot be told from twin A: refused, not resumed
    unnamed, _, _ = calibrate(free_top_link, second_machine, ("top",), progress=progress)
    assert isinstance(unnamed, SensorCalibrationError), unnamed
    assert "recorded on twin A, and this machine is not named" in str(unnamed)
    again, _, _ = calibrate(free_top_link, first_machine, ("top",), progress=progress, machine="twin A", log=log.append)
    assert again["top"] == done["top"]
    assert log[0] == f"resuming from {progress} (recorded {rec['saved']} on twin A): keeping top low, top high"


def test_the_link_must_be_the_calibration_link(model):
    with SimRig(model, FAST) as rig:
        with pytest.raises(SensorCalibrationError, match="calibration_profile"):
            SensorCalibration(rig.link, rig, model.profile)


def test_the_written_profile_loads_with_the_fitted_counts_and_keeps_the_rest(tmp_path):
    text = sensor_profile_toml("thesis-t132", {"tilt": (25, 908), "lift": (29, 258)})
    path = tmp_path / "calibrated.toml"
    path.write_text(text)
    p, n = load_profile(path), load_profile("thesis-t132")
    assert (p.actuator("tilt").counts_min, p.actuator("tilt").counts_max) == (25, 908)
    assert (p.actuator("lift").counts_min, p.actuator("lift").counts_max) == (29, 258)
    assert p.actuator("top") == n.actuator("top") and p.geometry == n.geometry
    assert "# assumed: the neutral lift angle is mid-range." in text  # comments kept
    with pytest.raises(SensorCalibrationError, match="does not validate"):
        sensor_profile_toml("thesis-t132", {"tilt": (900, 25)})
    assert math.isfinite(p.actuator("tilt").min)


# -- detached: no implement, the top link unpinned at the mast ---------------------------------------------
def assert_fits_the_truth(fits, truth, nominal):
    assert set(fits) == {"lift", "tilt", "top", "left", "right"}
    for name, fit in fits.items():
        t = truth.profile.actuator(name)
        assert abs(fit.counts_min - t.counts_min) <= 1 and abs(fit.counts_max - t.counts_max) <= 1, name
        assert fit.low.stopped_by == fit.high.stopped_by == "relay"
    # the truth really differs from the nominal map (else the test proves nothing)
    assert any(
        (truth.profile.actuator(n).counts_min, truth.profile.actuator(n).counts_max)
        != (nominal.actuator(n).counts_min, nominal.actuator(n).counts_max)
        for n in fits
    )


def test_the_detached_calibration_profile_releases_only_the_top_link_angles():
    nominal = load_profile("thesis-t132")
    pinned, detached = calibration_profile(nominal), calibration_profile(nominal, detached=True)
    for name in ("top_link_yaw_max", "top_link_pitch_up_max", "top_link_pitch_down_max"):
        assert getattr(detached.limits, name) == pytest.approx(math.pi / 2)  # the schema's widest
        assert getattr(pinned.limits, name) == getattr(nominal.limits, name)
    keep = {"top_link_yaw_max", "top_link_pitch_up_max", "top_link_pitch_down_max"}
    assert detached.limits.model_dump(exclude=keep) == pinned.limits.model_dump(exclude=keep)
    assert detached.actuators == pinned.actuators and detached.geometry == pinned.geometry
    assert detached.name != pinned.name
    with pytest.raises(SensorCalibrationError, match="detached must be true or false"):
        calibration_profile(nominal, detached="yes")


def test_detached_all_five_cylinders_of_the_thesis_profile_fit_the_truth_within_one_count():
    nominal = load_profile("thesis-t132")
    truth = truth_of(nominal, 1)
    with SimRig(HitchModel(calibration_profile(nominal, detached=True)), FAST, truth=truth) as rig:
        rig.start()
        rig.run_until(0.5)
        fits = SensorCalibration(rig.link, rig, nominal, detached=True).run()
        # the twin moved each cylinder to both relays: the ECU enforces no top-link angle of its own
        assert rig.link.counters.references_refused == 0
    assert_fits_the_truth(fits, truth, nominal)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [2, 3])
def test_detached_all_five_cylinders_fit_the_truth_for_more_tape_perturbed_twins(seed):
    nominal = load_profile("thesis-t132")
    truth = truth_of(nominal, seed)
    with SimRig(HitchModel(calibration_profile(nominal, detached=True)), FAST, truth=truth) as rig:
        rig.start()
        rig.run_until(0.5)
        fits = SensorCalibration(rig.link, rig, nominal, detached=True).run()
    assert_fits_the_truth(fits, truth, nominal)


def test_detached_is_refused_with_an_implement_and_needs_the_detached_link():
    nominal = load_profile("thesis-t132")
    plough = ImplementRecord("plough", "2", 600.0, (0.0, 1.0, 0.3))
    with SimRig(HitchModel(calibration_profile(nominal, detached=True)), FAST) as rig:
        with pytest.raises(SensorCalibrationError, match="no implement is attached: it cannot go with the implement"):
            SensorCalibration(rig.link, rig, nominal, detached=True, implement=plough)
        with pytest.raises(SensorCalibrationError, match=r"calibration_profile\(nominal, detached=False\)"):
            SensorCalibration(rig.link, rig, nominal)  # a detached link for a pinned calibration
    with SimRig(HitchModel(calibration_profile(nominal)), FAST) as rig:
        with pytest.raises(SensorCalibrationError, match=r"calibration_profile\(nominal, detached=True\)"):
            SensorCalibration(rig.link, rig, nominal, detached=True)  # the link would refuse the top-link angles


def test_detached_keeps_the_ground_clearance_and_the_keep_outs():
    data = load_profile("thesis-t132").model_dump(mode="python")
    data["limits"]["ground_clearance"] = 0.30  # lower-link ends at least 0.2 m below the pivots: the lift's low end
    box = data["workspace"]["restricted"]["2"]
    box["z"] = (-0.1, box["z"][1])  # the box within that clearance (a profile's box must be, TrajectoryPlanner)
    low_ends = profile_from_dict(data)
    exc, rig, start = calibrate(low_ends, truth_of(low_ends, 1), ("lift",), detached=True)
    assert isinstance(exc, SensorCalibrationError) and "lift refused: ground_clearance_" in str(exc)
    assert np.array_equal(rig.ecu.piston_counts(), start)
    data = load_profile("thesis-t132").model_dump(mode="python")
    h = data["geometry"]["top_link_tractor_point"]
    data["limits"]["keep_out"] = [{"name": "at_the_mount", "centre": list(h), "radius": 0.05}]
    boxed = profile_from_dict(data)
    exc, _, _ = calibrate(boxed, truth_of(boxed, 1), ("top",), detached=True)
    assert isinstance(exc, SensorCalibrationError) and "top refused: keep_out:at_the_mount" in str(exc)


def test_an_ecu_configured_with_the_nominal_lift_travel_is_named_with_the_readings_and_the_travel_needed():
    """The lift is read from the rear hitch position, a fraction of the ECU's configured lift travel. An ECU
    on the nominal travel (as ``hitch ecu-sim`` was, with no way to change it) never lets the lift reach its
    first approach as the link reads it. Before, the error named no reading: "lift low: the approach to 39
    counts not reached within 120 s"."""
    from bridge.link.sensor_calibration import SensorCalibrationSettings

    nominal = load_profile("thesis-t132")
    cal = calibration_profile(nominal, detached=True)
    with SimRig(HitchModel(cal), FAST) as rig:
        lift = nominal.actuator("lift")
        rig.ecu._lift_calibration = (float(lift.counts_min), float(lift.counts_max))  # configured as nominal
        rig.start()
        rig.run_until(0.5)
        run = SensorCalibration(rig.link, rig, nominal, detached=True, settings=SensorCalibrationSettings(max_end_s=5))
        with pytest.raises(SensorCalibrationError) as exc:
            run.run(("lift",))
    text = str(exc.value)
    assert "not reached within 5 s (lift reads" in text and "reference 39" in text, text
    lo, hi = cal.actuator("lift").counts_min, cal.actuator("lift").counts_max
    assert f"lift travel, counts {lo} … {hi} (hitch ecu-sim --sensor-calibration)" in text, text


class _FaultAfterLog:
    """A driver (the rig's ticks) that injects ``fault`` into the ECU node at the first tick after the log
    line starting ``after`` (the link then latches a fault and stops streaming references)."""

    def __init__(self, rig, after: str, fault: dict) -> None:
        self.rig, self.after, self.fault, self.armed, self.injected_s = rig, after, fault, False, None
        self.lines: list[str] = []

    @property
    def now_s(self) -> float:
        return self.rig.now_s

    def log(self, line: str) -> None:
        self.lines.append(line)
        if line.startswith(self.after):
            self.armed = True

    def tick(self) -> float:
        if self.armed and self.injected_s is None:
            self.rig.node.apply_fault(self.fault)
            self.injected_s = self.rig.now_s
        return self.rig.tick()


@pytest.mark.parametrize("fault", [{"restart_ecu": True}, {"cut": "both"}])
def test_a_link_fault_during_a_wait_stops_at_once_naming_it_and_keeps_the_progress(free_top_link, tmp_path, fault):
    """Over a remote bus a link fault stopped the reference stream; the wait for the approach ran its 120 s and
    then blamed the lift travel ("the approach to 242 counts not reached within 120 s … must be the calibration
    link's lift travel"). The wait now checks the link each tick and names the fault's reason."""
    from bridge.link.sensor_calibration import SensorCalibrationSettings

    truth = truth_of(free_top_link, 2)
    progress = tmp_path / "progress.json"
    cal = calibration_profile(free_top_link)
    with SimRig(HitchModel(cal), FAST, truth=truth) as rig:
        rig.start()
        rig.run_until(0.5)
        driver = _FaultAfterLog(rig, "top low:", fault)
        run = SensorCalibration(
            rig.link,
            driver,
            free_top_link,
            progress=progress,
            log=driver.log,
            settings=SensorCalibrationSettings(max_end_s=30),
        )
        with pytest.raises(SensorCalibrationError) as exc:
            run.run(("top",))
        stopped_after = rig.now_s - driver.injected_s
        reasons = rig.link.faults.reasons
    text = str(exc.value)
    assert driver.injected_s is not None, driver.lines
    assert stopped_after < 2.0, (stopped_after, text)  # not the wait's 30 s
    assert "the link stopped streaming references: " in text and "not reached within" not in text, text
    assert reasons and reasons[0] in text, (reasons, text)
    assert "top: the hold" in text and f"kept in {progress}" in text and "resume" in text, text
    rec = json.loads(progress.read_text())
    assert "low" in rec["actuators"]["top"] and "high" not in rec["actuators"]["top"]
    # the resume finds only the high end and fits the truth
    again, _, _ = calibrate(free_top_link, truth, ("top",), progress=progress)
    assert not isinstance(again, Exception), again
    t = truth.profile.actuator("top")
    assert abs(again["top"].counts_min - t.counts_min) <= 1 and abs(again["top"].counts_max - t.counts_max) <= 1


def test_two_calibrations_on_one_progress_file_are_refused_until_the_first_has_ended(free_top_link, tmp_path):
    """A commissioning trial: a resume ran while the first run (its background job) still wrote the same progress
    file; both finished, each writing its ends over the other's. The second is refused naming the first, before
    anything moves; once the first has ended (returned, raised or refused) the file can be resumed."""
    truth = truth_of(free_top_link, 2)
    progress = tmp_path / "progress.json"
    with SimRig(HitchModel(calibration_profile(free_top_link)), FAST, truth=truth) as rig:
        first = SensorCalibration(rig.link, rig, free_top_link, progress=progress)
        start = rig.ecu.piston_counts()
        with pytest.raises(SensorCalibrationError, match=rf"progress file {progress} is in use .*\(pid \d+\)"):
            SensorCalibration(rig.link, rig, free_top_link, progress=progress)
        assert np.array_equal(rig.ecu.piston_counts(), start)
        first.close()
        SensorCalibration(rig.link, rig, free_top_link, progress=progress).close()  # free again
    done, _, _ = calibrate(free_top_link, truth, ("top",), progress=progress)  # a run gives it up when it ends
    assert not isinstance(done, Exception), done
    again, _, _ = calibrate(free_top_link, truth, ("top",), progress=progress)
    assert not isinstance(again, Exception) and again["top"] == done["top"], again
