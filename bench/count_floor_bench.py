"""Why the pose error has a floor of about one AD count: rounding to whole counts and where the ECU stops.

The references are whole 10-bit counts (0xFF21) and the ECU controls each cylinder to its count, so a
commanded pose carries two errors of about half a count each:

* **rounding** — the commanded count minus the exact inverse's unrounded count. Static, with the pistons at
  the centres of their counts, for ``--poses`` random workspace poses (exact profile): each actuator rounded
  to its nearest count, and the best of the 2⁵ floor/ceil combinations per pose (the one with the smallest
  largest error / 2 mm or 2 mrad: what choosing counts jointly could gain).
* **the stop** — where the twin's ECU leaves the piston inside its count's band after a real goto
  (:class:`bridge.sim.accuracy_run._TwinGotos`: the planner's goto with the calibration bench's final
  approach, the unit loops, CAN, the identified hydraulics; exact profile, no play), for ``--visits`` poses.

Printed per actuator: mean and sd [counts] of piston − commanded count, commanded − unrounded, and
piston − unrounded; and the pose error (x, z [mm], roll, pitch [mrad]) mean, sd and p95 of each part.

Run: .venv/bin/python bench/count_floor_bench.py [--poses 200] [--visits 40] [--json FILE]
"""

from __future__ import annotations

import argparse
import itertools
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from _common import machine_note, write_json  # noqa: E402
from calibration_bench import DOF, FINAL_APPROACH, TARGET  # noqa: E402

from bridge.sim.accuracy_run import AccuracyRunSettings, _TwinGotos, measure_stop_offsets  # noqa: E402
from bridge.sim.truth import MachineTruth, PinPlay  # noqa: E402
from planner.calibration.design import candidate_poses  # noqa: E402
from planner.calibration.parametric import ParametricModel  # noqa: E402
from planner.model.exact_inverse import ExactInverse  # noqa: E402
from planner.model.kinematics import HitchModel  # noqa: E402
from planner.model.sensors import SensorScaling  # noqa: E402
from planner.model.types import ACTUATOR_NAMES  # noqa: E402
from planner.profiles import load_profile, profile_from_dict  # noqa: E402


def _pose_figures(err: np.ndarray) -> dict:
    """mean, sd, p95 of |·| per DOF in mm / mrad."""
    e = 1e3 * err
    return {
        "mean": e.mean(axis=0).tolist(),
        "sd": e.std(axis=0).tolist(),
        "p95": np.percentile(np.abs(e), 95, axis=0).tolist(),
    }


def _count_figures(d: np.ndarray) -> dict:
    return {"mean": d.mean(axis=0).tolist(), "sd": d.std(axis=0).tolist()}


def rounding(model: HitchModel, poses: np.ndarray) -> dict:
    """The static rounding error: nearest count per actuator vs the best floor/ceil combination."""
    inv, sc = ExactInverse(model), SensorScaling(model.profile)

    def pose_of(counts) -> np.ndarray:
        return np.array(model.pose(sc.to_si(counts, tolerance_counts=1.0)).controlled())

    near, best = [], []
    for p in poses:
        c = sc.counts_of(inv.solve(p)[0])
        near.append(pose_of(np.rint(c)) - p)
        errs = [pose_of(k) - p for k in itertools.product(*[(np.floor(v), np.ceil(v)) for v in c])]
        best.append(min(errs, key=lambda e: float(np.max(1e3 * np.abs(e) / TARGET))))  # TARGET in mm, mrad
    return {"nearest": _pose_figures(np.array(near)), "best_of_32": _pose_figures(np.array(best))}


def stops(profile, poses: np.ndarray, count_approach: dict | None = None) -> dict:
    """Real gotos on the twin (exact profile, no play): where the pistons stop, and the pose error; with
    ``count_approach`` (a ``motion.count_approach`` table) every goto ends with it."""
    data = profile.model_dump()
    data["motion"]["final_approach"] = FINAL_APPROACH
    data["motion"]["count_approach"] = count_approach
    prof = profile_from_dict(data)
    model = HitchModel(prof)
    sc = SensorScaling(prof)
    stop, rnd, err, refused = [], [], [], 0
    with _TwinGotos(
        model, MachineTruth(profile, PinPlay(0.0, 0.0)), model.neutral_pose.controlled(), AccuracyRunSettings()
    ) as tw:
        for k, p in enumerate(poses):
            try:
                tw.goto(dict(zip(DOF, map(float, p), strict=True)), f"poses[{k}]")
            except ValueError:  # PlanError: out of reach with the final approach
                refused += 1
                continue
            ecu = tw.rig.ecu
            ref = ecu.reference_counts()
            if ref is None:
                refused += 1
                continue
            unrounded = sc.counts_of(tw.tp.inverse.solve(p)[0])
            stop.append(ecu.piston_counts() - ref)
            rnd.append(ref - unrounded)  # with the count approach: its chosen count, not the nearest
            err.append(tw.rig.true_pose().controlled() - p)
    s, r = np.array(stop), np.array(rnd)
    return {
        "visited": len(stop),
        "refused": refused,
        "piston_minus_commanded": _count_figures(s),
        "commanded_minus_unrounded": _count_figures(r),
        "piston_minus_unrounded": _count_figures(s + r),
        "pose_error": _pose_figures(np.array(err)),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, default=200, help="random workspace poses for the static rounding")
    ap.add_argument("--visits", type=int, default=40, help="random workspace poses visited by gotos on the twin")
    ap.add_argument("--json", default=None, help="write the results as JSON")
    ap.add_argument(
        "--count-approach",
        action="store_true",
        help="also: measure the twin's stop offsets and visit the same poses with the count approach",
    )
    a = ap.parse_args()
    if not 1 <= a.poses <= 10_000 or not 1 <= a.visits <= 1000:
        ap.error("--poses must be in [1, 10000] and --visits in [1, 1000]")
    profile = load_profile("thesis-t132")
    model = HitchModel(profile)
    pm = ParametricModel(profile)
    t0 = time.perf_counter()
    res: dict = {"machine": machine_note()}
    res["rounding"] = rounding(model, candidate_poses(pm, a.poses, random_only=True, seed=7)[0])
    visits = candidate_poses(pm, a.visits, random_only=True, seed=3)[0]
    res["stops"] = stops(profile, visits)
    if a.count_approach:
        # the offsets measured on other poses of the twin than those then visited
        off = measure_stop_offsets(model, candidate_poses(pm, 10, random_only=True, seed=11)[0])
        res["stop_offsets"] = {
            "from_below": off.from_below,
            "from_above": off.from_above,
            "sd_below": off.sd_below,
            "sd_above": off.sd_above,
            "n": off.n,
        }
        table = off.table()
        res["stops_count_approach"] = stops(profile, visits, table)
    res["wall_s"] = time.perf_counter() - t0
    write_json(a.json, res)

    def row(name: str, f: dict) -> str:
        return f"{name:<44} " + "  ".join(f"{k} {np.round(f[k], 2).tolist()}" for k in f)

    print("pose error [x, z mm; roll, pitch mrad]")
    print(row("static, nearest count", res["rounding"]["nearest"]))
    print(row("static, best of the 2^5 floor/ceil", res["rounding"]["best_of_32"]))
    st = res["stops"]
    print(row(f"through the twin ({st['visited']} gotos)", st["pose_error"]))
    print(f"\nper actuator {ACTUATOR_NAMES} [counts]")
    for key in ("piston_minus_commanded", "commanded_minus_unrounded", "piston_minus_unrounded"):
        print(row(key, st[key]))
    if a.count_approach:
        off = res["stop_offsets"]
        print(f"\nstop offsets on the twin ({off['n']} poses) [counts], piston - count, {ACTUATOR_NAMES}")
        for key in ("from_below", "from_above", "sd_below", "sd_above"):
            print(f"{key:<44} {[[round(x, 3) for x in v] for v in off[key]]}")
        sc = res["stops_count_approach"]
        print(row(f"through the twin, count approach ({sc['visited']} gotos)", sc["pose_error"]))
        for key in ("piston_minus_commanded", "commanded_minus_unrounded", "piston_minus_unrounded"):
            print(row(key, sc[key]))
    print(f"\n{res['wall_s']:.0f} s wall")
    return 0


if __name__ == "__main__":
    sys.exit(main())
