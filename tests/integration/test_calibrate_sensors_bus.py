"""``hitch calibrate sensors`` on a CAN bus: the ECU in its own process (``hitch ecu-sim`` on a perturbed truth),
the calibration over the loopback hub in real time. Before, the command had no bus options and always
calibrated an in-process simulation of the nominal profile, saying nothing (a commissioning engineer's report).
The lift too: it is read from the rear hitch position, a fraction of the ECU's lift travel, which ``ecu-sim
--sensor-calibration`` sets to the calibration link's. Before, ecu-sim could not be configured so, and the lift's
first approach was never reached (a second engineer's report: "not reached within 120 s", no reading named)."""

import subprocess
import sys

import pytest

from bridge.cli import main
from bridge.link.loopback import LoopbackHub
from planner.profiles.hitch import load_profile

pytestmark = pytest.mark.slow


def test_calibrating_the_ecu_on_the_bus_recovers_its_true_ad_map(tmp_path, capsys):
    truth = tmp_path / "truth.toml"
    assert main(["sim", "perturb", "--seed", "2", "--tape", "--out", str(truth)]) == 0
    true_top, true_lift = (load_profile(truth).actuator(a) for a in ("top", "lift"))
    nominal_top, nominal_lift = (load_profile("thesis-t132").actuator(a) for a in ("top", "lift"))
    assert (true_top.counts_min, true_top.counts_max) != (nominal_top.counts_min, nominal_top.counts_max)
    assert (true_lift.counts_min, true_lift.counts_max) != (nominal_lift.counts_min, nominal_lift.counts_max)
    out = tmp_path / "cal.toml"
    with LoopbackHub() as hub:
        ecu = subprocess.Popen(
            [sys.executable, "-m", "bridge.cli.main", "ecu-sim", "--interface", "remote", "--channel", hub.url]
            + ["--sim-truth", str(truth), "--sensor-calibration", "--duration", "150"],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            capsys.readouterr()
            args = ["calibrate", "sensors", "--can-interface", "remote", "--can-channel", hub.url]
            rc = main([*args, "--actuators", "top,lift", "--detached", "--yes", "--out", str(out)])
            text = capsys.readouterr().out
        finally:
            ecu.terminate()
            ecu.wait(10)
    assert rc == 0, text
    assert f"calibrating the ECU on remote {hub.url}" in text and "simulated twin" not in text
    assert "the ECU must be configured with the calibration link's lift travel, counts 16 … 265" in " ".join(
        text.split()
    )
    for name, true in (("top", true_top), ("lift", true_lift)):
        fitted = load_profile(out).actuator(name)
        assert abs(fitted.counts_min - true.counts_min) <= 1 and abs(fitted.counts_max - true.counts_max) <= 1, name


def test_a_bus_without_an_ecu_is_named_within_seconds_and_the_twin_says_it_is_one(tmp_path, capsys):
    with LoopbackHub() as hub:
        args = ["calibrate", "sensors", "--can-interface", "remote", "--can-channel", hub.url, "--actuators", "top"]
        assert main([*args, "--out", str(tmp_path / "x.toml")]) == 2
    err = capsys.readouterr().err
    assert "no address claimed or no complete measurement from the ECU on remote" in err and "Traceback" not in err
    args = ["calibrate", "sensors", "--can-interface", "remote", "--sim-truth", "t.toml", "--out", "x.toml"]
    assert main(args) == 2
    assert "give one of them" in capsys.readouterr().err
