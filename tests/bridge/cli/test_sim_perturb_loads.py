"""``hitch sim perturb`` loads its ``--profile`` as ``hitch profile show`` does before it draws, and writes only a
truth that loads there (docs/profiles.md: the commands that write a truth "write nothing that would not load
there"). A commissioning trial: ``sim perturb --profile slips/sign3.toml --out x.toml`` wrote x.toml of a
profile whose neutral pose does not close; ``profile show --profile x.toml`` then failed."""

from __future__ import annotations

from importlib import resources

from bridge.cli.main import main
from planner.model.kinematics import HitchModel
from planner.profiles.hitch import load_profile

THESIS = (resources.files("planner") / "profiles" / "thesis-t132.toml").read_text()


def _profile(tmp_path, name: str, old: str, new: str):
    assert THESIS.count(old) == 1
    path = tmp_path / name
    path.write_text(THESIS.replace(old, new))
    return path


def run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_a_profile_whose_neutral_pose_does_not_close_is_refused_and_nothing_written(tmp_path, capsys):
    sign3 = _profile(
        tmp_path, "sign3.toml", "limiter_tractor_point = [0.1486666,", "limiter_tractor_point = [-0.1486666,"
    )
    out = tmp_path / "x.toml"
    argv = ("sim", "perturb", "--seed", "1", "--tape", "--profile", str(sign3))
    code, stdout, err = run(capsys, *argv, "--out", str(out))
    assert code == 2 and stdout == ""
    assert f"--profile {sign3} does not load (category 2): profile thesis-t132: cannot find the neutral pose" in err
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["sign3.toml"]
    code, stdout, err = run(capsys, *argv)  # printed, not written
    assert code == 2 and stdout == "" and "cannot find the neutral pose" in err


def test_a_drawn_truth_that_would_not_load_is_refused_and_another_seed_is_written(tmp_path, capsys):
    tight = _profile(tmp_path, "tight.toml", "min = 0.655\nmax = 0.905", "min = 0.655\nmax = 0.742683")
    HitchModel(load_profile(tight))  # the nominal loads (its neutral needs 0.742483 m of top link)
    out = tmp_path / "truth.toml"
    code, _, err = run(capsys, "sim", "perturb", "--seed", "3", "--tape", "--profile", str(tight), "--out", str(out))
    assert code == 2
    assert "the drawn truth thesis-t132-truth-3 (seed 3) does not load (category 2)" in err
    assert "outside its stroke actuators.top" in err and "the draw is refused" in err
    assert not out.exists()
    code, _, err = run(capsys, "sim", "perturb", "--seed", "0", "--tape", "--profile", str(tight), "--out", str(out))
    assert code == 0, err
    HitchModel(load_profile(out))  # what `hitch profile show --profile truth.toml` builds
