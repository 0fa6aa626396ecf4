"""Geometry calibration on tape-perturbed twins: uncalibrated vs calibrated from planned or random poses.

For each twin (``perturb_profile(seed)``, tape errors and pin play) the instrument (total station:
1 mm / 1 mrad, Gaussian) measures the poses — planned (D-optimal, ``hitch calibrate plan-poses``)
or random workspace poses — each approached from both sides (the play averages out). The profile is
calibrated from the measurements (as ``hitch calibrate geometry`` does: with the tape prior, its default;
``--no-tape-prior`` here: the plain least squares); then 200 random workspace poses are commanded through each
profile's exact inverse, and the true machine's pose (truth geometry and AD map, rigid implement) is
compared with the commanded pose: the error p95 per DOF, in two evaluations:

* **no quantisation** (idealised): the pistons at exactly the commanded, unrounded counts, play centred;
* **with quantisation** (physical, as on the machine): the commanded counts rounded to whole counts,
  each true piston drawn uniformly within ± 0.5 count of the true AD map (the ECU stops when the reading
  equals the count), and the twin's pin play, every pose approached from a random side in every DOF.

The calibration measurements are as ``hitch calibrate measure-twin`` takes them (pistons at the whole
counts); ``planned20_dither`` also calibrates from measurements with the pistons anywhere in their
count's band and evaluates it with quantisation. Also: identified directions (and single parameters)
within 3 σ of the truth, calibration run time.

**Through the twin** (``--through-twin N``, the first N twins, default all; on ``--workers`` processes;
``--skip-static`` runs only this part):
the machine as it runs, nothing assumed about where a piston stops. The profile carries a final approach
(:data:`FINAL_APPROACH`: every goto ends rising in every DOF); the 20 poses planned on that profile (each
reached with its whole approach: not at the box's lower faces) are measured as
``hitch calibrate measure-twin --by goto`` does (a real goto over CAN to each, the link's counts at rest,
the station reading the true pose), the profile is calibrated from them, and the 200 check poses are
visited by real gotos, in a nearest-neighbour tour, with the nominal and the calibrated profile: error =
the twin's true pose − the commanded pose. Its floor: a profile equal to the truth, without and with
1 mm of play, visited the same way.

The check poses are random workspace poses (``candidate_poses(random_only=True)``: not the box's corners
and face centres, where an approach from below is cut short). A calibrated machine that cannot reach the
nominal box (the planner refuses to load it) gets the box of ``hitch profile fit-workspace`` where smaller, as
docs/commissioning.md tells a user; its check poses outside it are refused and not counted (the improvement factor is
also given with the uncalibrated error on the same poses, "same poses").

``--without-play``: the twins through the twin without their pin play (each truth otherwise as drawn), to show
what the play does to the accuracy and to the identified parameters.

``--count-approach``: every goto (measuring, calibrated, floors) ends with the profile's count approach, its
stop offsets measured once on the nominal twin (:func:`twin_count_approach`).

``--two-sided``: through the twin, each planned pose is measured twice, by a goto with the final approach from
below and one with its mirror image from above (``hitch calibrate measure-twin --by goto --sides both``; the
poses planned with the approach's room at both faces). The fit then also finds the lag the pin play leaves
(``lag.*``, compared with the truth's play band) and the calibrated profile's planner aims each goto beyond its
goal by it (as ``hitch calibrate geometry`` does for a file whose ``approach`` column names both sides; from
one side the lag is not fitted). The lag's truth
for the identified directions' |z| is the lag the measurements hold: side · (true implement − true mechanism
pose) averaged over the rows (the count step can leave the play a little short of its band's edge); the
|z| against the play's band itself is given beside it.

Run: .venv/bin/python bench/calibration_bench.py [--twins 20] [--json bench/out/calibration.json] [--plot PNG]
     [--through-twin N] [--workers 2] [--skip-static] [--count-approach] [--check 200] [--check-seed 999]
     [--twin-plot PNG] [--without-play] [--two-sided] [--no-tape-prior]
"""

from __future__ import annotations

import argparse
import multiprocessing
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from _common import machine_note, write_json  # noqa: E402

from bridge.sim.accuracy_run import AccuracyRunSettings, measure_stop_offsets, visit_poses  # noqa: E402
from bridge.sim.calibration_data import measure_twin, true_poses  # noqa: E402
from bridge.sim.truth import MachineTruth, PinPlay, TrueMachine, perturb_profile  # noqa: E402
from planner.calibration.design import candidate_poses, plan_poses  # noqa: E402
from planner.calibration.measurements import MeasurementSet  # noqa: E402
from planner.calibration.parameters import ParameterSet  # noqa: E402
from planner.calibration.parametric import ParametricModel  # noqa: E402
from planner.calibration.solve import build_calibration_problem, solve_calibration  # noqa: E402
from planner.model.kinematics import HitchModel  # noqa: E402
from planner.model.sensors import SensorScaling  # noqa: E402
from planner.model.workspace import fit_restricted_box  # noqa: E402
from planner.profiles.hitch import load_profile, profile_from_dict  # noqa: E402
from planner.trajectory import PlanError, TrajectoryPlanner  # noqa: E402

TARGET = np.array([2.0, 2.0, 2.0, 2.0])  # x, z [mm], roll, pitch [mrad] p95
DOF = ("x", "z", "roll", "pitch")
#: the profile's motion.final_approach through the twin: > 2 play bands of 1 mm of play (1, 1 mm, 2.3, 3.3 mrad)
FINAL_APPROACH = {"x": 0.0025, "z": 0.004, "roll": 0.005, "pitch": 0.007}


def _tour(poses: np.ndarray) -> np.ndarray:
    """The poses in a nearest-neighbour order (angles weighted 0.5 m/rad): short gotos between them."""
    w = np.array([1.0, 1.0, 0.5, 0.5])
    order, left = [0], list(range(1, len(poses)))
    while left:
        d = np.sum(((poses[left] - poses[order[-1]]) / w) ** 2, axis=1)
        order.append(left.pop(int(np.argmin(d))))
    return poses[order]


def _floor_through_twin(job: tuple) -> dict:
    """The floor through the twin: the profile equal to the truth (with or without 1 mm of play), real gotos."""
    play_m, prof_data, check = job
    prof = profile_from_dict(prof_data)
    truth = MachineTruth(load_profile("thesis-t132"), PinPlay(play_m, play_m))
    v = visit_poses(HitchModel(prof), check, truth, AccuracyRunSettings(seed=0), skip_refused=True)
    err = (v.true - check) * 1e3
    return {
        "play_m": play_m,
        "p95": np.nanpercentile(np.abs(err), 95, axis=0).tolist(),
        "mean": np.nanmean(err, axis=0).tolist(),
        "sd": np.nanstd(err, axis=0).tolist(),
        "refused": len(v.refused),
    }


def _through_twin(job: tuple) -> dict:
    """One twin through the running twin (module docstring): p95 nominal / calibrated, refused poses, times."""
    seed, prof_data, planned, check, without_play, two_sided, tape_prior = job
    prof = profile_from_dict(prof_data)
    pm = ParametricModel(prof, params=ParameterSet.from_profile(prof, include_lag=two_sided))  # as the CLI
    data, play = perturb_profile(load_profile("thesis-t132"), seed)
    truth = MachineTruth(profile_from_dict(data), PinPlay() if without_play else play)
    t0 = time.perf_counter()
    res, cal_profile, _, tm = _calibrate(
        pm, truth, planned, seed, by="goto", approach="both" if two_sided else None, tape_prior=tape_prior
    )
    cal, fitted = _reachable_box(HitchModel(cal_profile))
    # the lag the measurements hold: side · (implement − mechanism), averaged (the count step may leave the play
    # a little short of its band's edge in some DOF)
    lag_held = np.mean(tm.sides[:, None] * tm.play_offset, axis=0)
    z, _ = _z_scores(pm, res, truth, lag_held)  # the identified directions against truth, in their σ
    z_band, _ = _z_scores(pm, res, truth)  # the same with the play's band as the lag's truth
    li = pm.params.lag_index
    out: dict = {
        "seed": seed,
        "measure_and_fit_wall_s": time.perf_counter() - t0,
        "box_fitted": fitted,
        "z_max": float(z.max()),
        "within_3sigma": int(np.sum(z <= 3.0)),
        "identified": int(z.size),
        "z_abs": z.tolist(),
        "lag_fitted": res.values[li].tolist(),
        "lag_std": res.std[li].tolist(),
        "lag_truth": _truth_values(pm, truth)[li].tolist(),
        "lag_held": lag_held.tolist(),
        "within_3sigma_lag_band": int(np.sum(z_band <= 3.0)),
        "z_max_lag_band": float(z_band.max()),
        "lag_identified_share": res.identified_share[li].tolist(),
    }
    errs = {}
    for name, model in (("nominal", pm.nominal_model), ("calibrated", cal)):
        t0 = time.perf_counter()
        v = visit_poses(model, check, truth, AccuracyRunSettings(seed=seed), skip_refused=True)
        errs[name] = np.abs(v.true - check) * 1e3
        out[name] = np.nanpercentile(errs[name], 95, axis=0).tolist()
        out[f"{name}_refused"] = [k for k, _ in v.refused]
        out[f"{name}_wall_s"] = time.perf_counter() - t0
        out[f"{name}_simulated_s"] = v.simulated_s
    kept = np.all(np.isfinite(errs["calibrated"]), axis=1)  # the uncalibrated error on the poses counted calibrated
    out["nominal_same_poses"] = np.nanpercentile(errs["nominal"][kept], 95, axis=0).tolist()
    out["errors"] = errs  # |error| per check pose (NaN: refused), for the error map; not written to the JSON
    return out


def _twin_error_map(path: str, check: np.ndarray, twin: dict, count_approach: bool) -> None:
    """The error map through the twin of ``twin`` (its per-pose errors): uncalibrated and calibrated, each DOF over
    the check poses' x and z; refused poses are grey crosses."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 4, figsize=(17, 7.5), sharex=True, sharey=True)
    for row_i, name in enumerate(("nominal", "calibrated")):
        e = twin["errors"][name]
        ok = np.all(np.isfinite(e), axis=1)
        for k, d in enumerate(DOF):
            ax = axes[row_i, k]
            sca = ax.scatter(1e3 * check[ok, 0], 1e3 * check[ok, 1], c=e[ok, k], s=14, cmap="viridis")
            if not np.all(ok):
                ax.scatter(1e3 * check[~ok, 0], 1e3 * check[~ok, 1], c="0.6", marker="x", s=14, label="refused")
                ax.legend(loc="lower right", fontsize=7)
            fig.colorbar(sca, ax=ax, label=f"|{d} error| [{'mm' if k < 2 else 'mrad'}]")
            label = "uncalibrated" if name == "nominal" else "calibrated"
            ax.set_title(f"{label}: {d}\np95 {np.nanpercentile(e[:, k], 95):.2f} (target {TARGET[k]:g})", fontsize=9)
            ax.set_xlabel("x [mm]")
            ax.set_ylabel("z [mm]")
    how = "final and count approach" if count_approach else "final approach"
    fig.suptitle(
        f"through the twin (real gotos over CAN, {how}): pose error over {len(check)} random workspace poses, "
        f"twin {twin['seed']} (the worst: largest calibrated p95 / target)"
    )
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    print(f"wrote {path}", flush=True)


def _reachable_box(model: HitchModel) -> tuple[HitchModel, dict | None]:
    """``model``, or where the calibrated machine cannot reach its restricted box (the planner refuses to load
    it, as for twin 0: the true machine cannot reach that corner within the top link's yaw limit either), what
    docs/commissioning.md tells the user to do: the box of ``hitch profile fit-workspace`` wherever it is
    smaller. Returns the model and the box put in (None: kept)."""
    try:
        TrajectoryPlanner(model)
        return model, None
    except PlanError:
        pass
    fit = fit_restricted_box(model).box
    cat = model.category
    data = model.profile.model_dump()
    old = data["workspace"]["restricted"][cat]
    box = {k: (max(float(old[k][0]), float(fit[k][0])), min(float(old[k][1]), float(fit[k][1]))) for k in fit}
    data["workspace"]["restricted"][cat] = box
    return HitchModel(profile_from_dict(data), cat), box


def _calibrate(
    pm: ParametricModel,
    truth: MachineTruth,
    poses: np.ndarray,
    seed: int,
    dither: bool = False,
    by: str = "static",
    approach: str | None = None,
    tape_prior: bool = True,
):
    """Measure ``poses`` on the twin (``measure_twin(..., by=by, approach=approach)``, station noise) and calibrate
    from them: (result, calibrated profile, solver time [s], the twin measurements)."""
    tm = measure_twin(
        pm.nominal_model, truth, poses, noise="station", seed=seed, dither=dither, by=by, approach=approach
    )
    sc = SensorScaling(pm.profile)
    readings = sc.si_min + (tm.counts - sc.counts_min) * sc.resolution
    mask = np.isfinite(tm.measured)
    data = MeasurementSet(readings, tm.measured, mask, tuple(str(i) for i in range(len(readings))), tm.sides)
    t0 = time.perf_counter()
    res = solve_calibration(build_calibration_problem(pm, data), tape_prior=tape_prior)
    dt = time.perf_counter() - t0
    cal = profile_from_dict(pm.params.profile_dict(res.values))
    return res, cal, dt, tm


def _p95(
    model: HitchModel,
    truth: MachineTruth,
    check: np.ndarray,
    physical_seed: int | None = None,
    *,
    counts: bool = True,
    play: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Error p95 per DOF [mm, mrad] and the errors (N, 4); ``physical_seed``: the evaluation with quantisation
    (``counts`` / ``play`` False leave out the whole counts and band, or the play: the split of the two)."""
    if physical_seed is None:
        tp, _ = true_poses(model, truth, check)
    else:
        tp, _ = true_poses(
            model,
            truth,
            check,
            quantise=counts,
            dither=counts,
            play="random" if play else "centred",
            seed=physical_seed,
        )
    err = np.abs(tp - check) * 1e3
    return np.percentile(err, 95, axis=0), err


def _truth_values(pm: ParametricModel, truth: MachineTruth, lag: np.ndarray | None = None) -> np.ndarray:
    """The truth's parameter values: its profile's, and as its lag (if fitted) ``lag`` (default its play's band
    per DOF)."""
    v = pm.params.values_of(truth.profile)
    li, dofs = pm.params.lag_index, list(pm.params.lag_dofs)
    if li.size:
        v[li] = (TrueMachine(truth, pm.category).band if lag is None else np.asarray(lag))[dofs]
    return v


def _z_scores(
    pm: ParametricModel, res, truth: MachineTruth, lag: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """|z| of the identified directions (combinations) and of the single parameters (27, 31 with the lag; inf
    where σ = 0); the lag's truth ``lag`` (default the play's band)."""
    ps = pm.params
    du = (res.values - _truth_values(pm, truth, lag)) / ps.scale
    b = res.basis
    cov = b.T @ res.covariance_scaled @ b
    z_dir = np.abs(b.T @ du) / np.sqrt(np.maximum(np.diag(cov), 1e-300))
    sd = np.sqrt(np.maximum(np.diag(res.covariance_scaled), 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        z_par = np.where(sd > 0.0, np.abs(du) / np.where(sd > 0.0, sd, 1.0), np.where(np.abs(du) > 0.0, np.inf, 0.0))
    return z_dir, z_par


def twin_count_approach(prof) -> dict:
    """The ``motion.count_approach`` table of the twin's ECU: its stop offsets measured on the nominal twin (10
    random poses other than the check poses; :func:`bridge.sim.accuracy_run.measure_stop_offsets`), as a user
    measures them on the machine's twin once, whatever the geometry."""
    poses = candidate_poses(ParametricModel(prof), 10, random_only=True, seed=11)[0]
    return measure_stop_offsets(HitchModel(prof), poses).table()


def _run_through_twin(
    prof,
    n_twin: int,
    workers: int,
    check: np.ndarray,
    count_approach: bool = False,
    plot: str = "",
    without_play: bool = False,
    two_sided: bool = False,
    tape_prior: bool = True,
) -> dict:
    """The through-the-twin evaluation of the first ``n_twin`` twins (module docstring), its table and summary;
    ``count_approach``: every goto of every profile (measuring, calibrated, floors) ends with the count approach
    whose offsets :func:`twin_count_approach` measured. The 20 poses to measure are planned on the profile with
    its final approach (``hitch calibrate plan-poses``: each reached with its whole approach). ``without_play``:
    the twins without their pin play (the rest of each truth as drawn), to show what the play does."""
    data = prof.model_dump()
    data["motion"]["final_approach"] = FINAL_APPROACH
    if count_approach:
        data["motion"]["count_approach"] = twin_count_approach(prof)
        print(f"count approach: {data['motion']['count_approach']}", flush=True)
    planned = plan_poses(ParametricModel(profile_from_dict(data)), 20, two_sided=two_sided).poses
    jobs = [(seed, data, planned, check, without_play, two_sided, tape_prior) for seed in range(n_twin)]
    print(f"\nthrough the twin: {n_twin} twins on {workers} processes (final approach {FINAL_APPROACH})", flush=True)
    t0 = time.perf_counter()
    with multiprocessing.get_context("fork").Pool(max(1, workers)) as pool:
        floors = pool.map(_floor_through_twin, [(play_m, data, check) for play_m in (0.0, 0.001)])
        for f in floors:
            print(
                f"floor (profile = truth, play {1e3 * f['play_m']:g} mm): p95 {np.round(f['p95'], 2)}  mean "
                f"{np.round(f['mean'], 2)}  sd {np.round(f['sd'], 2)}  refused {f['refused']}",
                flush=True,
            )
        res = []
        for r in pool.imap(_through_twin, jobs):
            res.append(r)
            n, c = np.asarray(r["nominal"]), np.asarray(r["calibrated"])
            same = np.asarray(r["nominal_same_poses"])
            ok = "ok" if np.all(c <= TARGET) else "MISS"
            print(
                f"{r['seed']:4d} | uncalibrated {' '.join(f'{v:6.2f}' for v in n)} | calibrated "
                f"{' '.join(f'{v:5.2f}' for v in c)} {ok:4s} | factor worst axis {n.max() / c.max():5.1f} "
                f"(same poses {same.max() / c.max():5.1f}) | |z| max {r['z_max']:5.2f} ({r['within_3sigma']}/"
                f"{r['identified']} ≤ 3σ) | lag [mm, mrad] {np.round(1e3 * np.array(r['lag_fitted']), 2)} ± "
                f"{np.round(1e3 * np.array(r['lag_std']), 2)} held {np.round(1e3 * np.array(r['lag_held']), 2)} band "
                f"{np.round(1e3 * np.array(r['lag_truth']), 2)} ({r['within_3sigma_lag_band']} ≤ 3σ against the band) "
                f"| refused "
                f"{len(r['nominal_refused'])}/{len(r['calibrated_refused'])} | {r['calibrated_simulated_s']:.0f} s "
                f"simulated in {r['calibrated_wall_s']:.0f} s",
                flush=True,
            )
    if not res:  # --through-twin 0: the floor alone
        return {
            "final_approach": FINAL_APPROACH,
            "count_approach": data["motion"].get("count_approach"),
            "floor_exact_profile": floors,
            "wall_s": time.perf_counter() - t0,
        }
    cal_p = np.array([r["calibrated"] for r in res])
    nom_p = np.array([r["nominal"] for r in res])
    worst = int(np.argmax(np.max(cal_p / TARGET, axis=1)))  # the largest calibrated p95 relative to its target
    if plot:
        _twin_error_map(plot, check, res[worst], count_approach)
    for r in res:
        r.pop("errors")
    return {
        "final_approach": FINAL_APPROACH,
        "count_approach": data["motion"].get("count_approach"),
        "tape_prior": tape_prior,
        "calibrated_max_p95": cal_p.max(axis=0).tolist(),
        "calibrated_median_p95": np.median(cal_p, axis=0).tolist(),
        "nominal_min_p95": nom_p.min(axis=0).tolist(),
        "nominal_max_p95": nom_p.max(axis=0).tolist(),
        "twins_within_target": int(np.sum(np.all(cal_p <= TARGET, axis=1))),
        "twins_within_target_per_dof": np.sum(cal_p <= TARGET, axis=0).tolist(),
        "improvement_min_worst_axis": float(np.min(nom_p.max(axis=1) / cal_p.max(axis=1))),
        "improvement_min_worst_axis_same_poses": float(
            np.min(np.array([r["nominal_same_poses"] for r in res]).max(axis=1) / cal_p.max(axis=1))
        ),
        "twin_worst_vs_target": res[worst]["seed"],
        "identified_within_3sigma": [f"{r['within_3sigma']}/{r['identified']}" for r in res],
        "twins_all_identified_within_3sigma": int(sum(r["within_3sigma"] == r["identified"] for r in res)),
        "twins_all_identified_within_3sigma_lag_band": int(
            sum(r["within_3sigma_lag_band"] == r["identified"] for r in res)
        ),
        "two_sided": two_sided,
        "z_max": max(r["z_max"] for r in res),
        # an honest σ gives z of RMS 1 over all the identified directions of all the twins
        "z_rms_all_directions": float(np.sqrt(np.mean(np.concatenate([r["z_abs"] for r in res]) ** 2))),
        "directions_beyond_3sigma": f"{sum(r['identified'] - r['within_3sigma'] for r in res)} of "
        f"{sum(r['identified'] for r in res)}",
        "refused_poses": [len(r["calibrated_refused"]) for r in res],
        "boxes_fitted": {r["seed"]: r["box_fitted"] for r in res if r["box_fitted"] is not None},
        "floor_exact_profile": floors,
        "wall_s": time.perf_counter() - t0,
        "twins": res,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--twins", type=int, default=20)
    ap.add_argument(
        "--no-tape-prior",
        action="store_true",
        help="calibrate by plain least squares (hitch calibrate geometry's option)",
    )
    ap.add_argument("--check", type=int, default=200, help="random workspace poses to check")
    ap.add_argument("--check-seed", type=int, default=999, help="seed of the random check poses")
    ap.add_argument("--json", default=None)
    ap.add_argument("--plot", default="docs/calibration_error_map.png", help="error map PNG ('' = none)")
    ap.add_argument(
        "--without-play",
        action="store_true",
        help="through the twin, the twins without their pin play (the rest of each truth as drawn)",
    )
    ap.add_argument(
        "--twin-plot",
        default="",
        help="error map PNG through the twin, of the worst twin (largest calibrated p95 / target) ('' = none)",
    )
    ap.add_argument("--through-twin", type=int, default=None, help="twins evaluated through the twin (default all)")
    ap.add_argument("--workers", type=int, default=2, help="processes for the through-the-twin runs")
    ap.add_argument("--skip-static", action="store_true", help="only the through-the-twin evaluation")
    ap.add_argument(
        "--two-sided",
        action="store_true",
        help="through the twin, measure each planned pose from below and from above (the fit finds the lag)",
    )
    ap.add_argument(
        "--count-approach",
        action="store_true",
        help="through the twin, every goto ends with the count approach (offsets measured on the nominal twin)",
    )
    args = ap.parse_args()
    if args.through_twin is not None and args.through_twin < 0:
        ap.error("--through-twin must be >= 0")
    prof = load_profile("thesis-t132")
    pm = ParametricModel(prof)
    nominal = HitchModel(prof)
    t0 = time.perf_counter()
    planned = {n: plan_poses(pm, n).poses for n in (10, 20)}
    t_plan = time.perf_counter() - t0
    pool, _ = candidate_poses(pm, 3000, seed=123)
    check, _ = candidate_poses(pm, 4 * args.check, seed=args.check_seed, random_only=True)
    check = _tour(check[: args.check])
    n_twin = args.twins if args.through_twin is None else args.through_twin

    def through_twin() -> dict:
        """The through-the-twin part with the options given."""
        return _run_through_twin(
            prof,
            n_twin,
            args.workers,
            check,
            args.count_approach,
            args.twin_plot,
            args.without_play,
            args.two_sided,
            not args.no_tape_prior,
        )

    if args.skip_static:
        res = through_twin()
        print(f"\nthrough_twin: { {k: v for k, v in res.items() if k != 'twins'} }")
        if args.json:
            write_json(args.json, {"machine": machine_note(), "summary": {"through_twin": res}})
        return
    exact = MachineTruth(prof)  # the floor: a profile equal to the truth, with quantisation / with 1 mm play
    floor_counts, _ = _p95(nominal, exact, check, 5000, play=False)
    floor_play, _ = _p95(nominal, MachineTruth(prof, PinPlay(0.001, 0.001)), check, 5000, counts=False)
    rows = []
    worst_map = None
    for seed in range(args.twins):
        data, play = perturb_profile(prof, seed)
        truth = MachineTruth(profile_from_dict(data), play)
        rng = np.random.default_rng(1000 + seed)
        phys = 5000 + seed  # seed of the band positions and approach sides of the evaluation with quantisation
        row: dict = {"seed": seed, "play_mm": [1e3 * play.lower_link_m, 1e3 * play.top_link_m]}
        row["nominal"], _ = _p95(nominal, truth, check)
        row["nominal_physical"], err_nom = _p95(nominal, truth, check, phys)
        cases = {
            "planned10": planned[10],
            "planned20": planned[20],
            "random20": pool[rng.choice(len(pool), 20, replace=False)],
            "random40": pool[rng.choice(len(pool), 40, replace=False)],
        }
        for name, poses in cases.items():
            res, cal, dt, _ = _calibrate(pm, truth, poses, seed, tape_prior=not args.no_tape_prior)
            cal_model = HitchModel(cal)
            row[name], err = _p95(cal_model, truth, check)
            row[f"{name}_physical"], err_phys = _p95(cal_model, truth, check, phys)
            row[f"{name}_time_s"] = dt
            row[f"{name}_identified"] = res.identified
            if name == "planned20":
                z, zp = _z_scores(pm, res, truth)
                row["planned20_z_max"] = float(z.max())
                row["planned20_within_3sigma"] = float(np.mean(z <= 3.0))
                row["planned20_params_within_3sigma"] = int(np.sum(zp <= 3.0))
                row["planned20_params_zero_std"] = int(np.sum(np.sqrt(np.diag(res.covariance_scaled)) <= 0.0))
                row["planned20_counts_only"], _ = _p95(cal_model, truth, check, phys, play=False)
                row["planned20_play_only"], _ = _p95(cal_model, truth, check, phys, counts=False)
                if worst_map is None or err_phys.max() > worst_map[2].max():
                    worst_map = (seed, err, err_phys, err_nom)
        res, cal, _, _ = _calibrate(pm, truth, planned[20], seed, dither=True, tape_prior=not args.no_tape_prior)
        row["planned20_dither_physical"], _ = _p95(HitchModel(cal), truth, check, phys)
        rows.append(row)
        r = row
        print(
            f"twin {seed:2d}: p95 x/z mm, roll/pitch mrad  nominal {np.round(r['nominal'], 2)}  "
            f"planned20 {np.round(r['planned20'], 2)}  planned10 {np.round(r['planned10'], 2)}  "
            f"random20 {np.round(r['random20'], 2)}  random40 {np.round(r['random40'], 2)}  "
            f"| with quantisation: nominal {np.round(r['nominal_physical'], 2)}  "
            f"planned20 {np.round(r['planned20_physical'], 2)}  "
            f"(dithered measurements {np.round(r['planned20_dither_physical'], 2)})  "
            f"z_max {r['planned20_z_max']:.2f} ({100 * r['planned20_within_3sigma']:.0f} % ≤ 3σ; "
            f"{r['planned20_params_within_3sigma']}/{len(pm.params.scale)} parameters)  "
            f"{r['planned20_time_s']:.2f} s",
            flush=True,
        )

    def evaluation(nom_key: str, cal_key: str) -> dict:
        cal_p = np.array([r[cal_key] for r in rows])
        nom_p = np.array([r[nom_key] for r in rows])
        return {
            "calibrated_max_p95": cal_p.max(axis=0).tolist(),
            "calibrated_worst_axis_p95_max": float(cal_p.max()),
            "nominal_min_p95": nom_p.min(axis=0).tolist(),
            "nominal_max_p95": nom_p.max(axis=0).tolist(),
            "twins_within_target": int(np.sum(np.all(cal_p <= TARGET, axis=1))),
            "twins_within_target_per_dof": np.sum(cal_p <= TARGET, axis=0).tolist(),
            "all_twins_within_target": bool(np.all(cal_p <= TARGET)),
            "improvement_min": float(np.min(nom_p.max(axis=1) / cal_p.max(axis=1))),
            "improvement_min_per_dof": (nom_p / cal_p).min(axis=0).tolist(),
            "twins_improved_5x_worst_axis": int(np.sum(nom_p.max(axis=1) / cal_p.max(axis=1) >= 5.0)),
            "twins_improved_5x_every_dof": int(np.sum(np.all(nom_p / cal_p >= 5.0, axis=1))),
            "median_worst_axis_p95": float(np.median(cal_p.max(axis=1))),
        }

    def table(title: str, nom_key: str, cal_key: str) -> None:
        print(f"\n{title}: p95 x, z [mm], roll, pitch [mrad]; improvement = uncalibrated / calibrated")
        print("twin | uncalibrated x z roll pitch | calibrated x z roll pitch | worst | factor x z roll pitch | worst")
        for r in rows:
            n, c = np.asarray(r[nom_key]), np.asarray(r[cal_key])
            ok = "ok" if np.all(c <= TARGET) else "MISS"
            print(
                f"{r['seed']:4d} | {' '.join(f'{v:6.2f}' for v in n)} | {' '.join(f'{v:5.2f}' for v in c)} | "
                f"{c.max():5.2f} {ok:4s} | {' '.join(f'{v:6.1f}' for v in n / c)} | {n.max() / c.max():6.1f}"
            )

    table("no quantisation (pistons at the unrounded commanded counts, play centred)", "nominal", "planned20")
    table(
        "with quantisation (whole counts, piston uniform in ± 0.5 count, play from a random side)",
        "nominal_physical",
        "planned20_physical",
    )
    summary = {
        "target_p95": TARGET.tolist(),
        "no_quantisation": evaluation("nominal", "planned20"),
        "with_quantisation": evaluation("nominal_physical", "planned20_physical"),
        "with_quantisation_dithered_measurements": evaluation("nominal_physical", "planned20_dither_physical"),
        "planned20_counts_only_max_p95": np.max([r["planned20_counts_only"] for r in rows], axis=0).tolist(),
        "planned20_play_only_max_p95": np.max([r["planned20_play_only"] for r in rows], axis=0).tolist(),
        "floor_exact_profile_counts_p95": floor_counts.tolist(),
        "floor_exact_profile_play_1mm_p95": floor_play.tolist(),
        "planned10_vs_random20_median_worst_dof": [
            float(np.median([max(r["planned10"]) for r in rows])),
            float(np.median([max(r["random20"]) for r in rows])),
        ],
        "planned20_vs_random40_median_worst_dof": [
            float(np.median([max(r["planned20"]) for r in rows])),
            float(np.median([max(r["random40"]) for r in rows])),
        ],
        "planned10_vs_random20_median_worst_dof_with_quantisation": [
            float(np.median([max(r["planned10_physical"]) for r in rows])),
            float(np.median([max(r["random20_physical"]) for r in rows])),
        ],
        "planned20_vs_random40_median_worst_dof_with_quantisation": [
            float(np.median([max(r["planned20_physical"]) for r in rows])),
            float(np.median([max(r["random40_physical"]) for r in rows])),
        ],
        "within_3sigma_fraction": float(np.mean([r["planned20_within_3sigma"] for r in rows])),
        "z_max": float(np.max([r["planned20_z_max"] for r in rows])),
        "params_within_3sigma_min_max": [
            int(np.min([r["planned20_params_within_3sigma"] for r in rows])),
            int(np.max([r["planned20_params_within_3sigma"] for r in rows])),
        ],
        "n_params": len(pm.params.scale),
        "calibration_time_s_median": float(np.median([r["planned20_time_s"] for r in rows])),
        "calibration_time_s_range": [
            float(np.min([r["planned20_time_s"] for r in rows])),
            float(np.max([r["planned20_time_s"] for r in rows])),
        ],
        "plan_time_s": t_plan,
    }
    summary["through_twin"] = through_twin()
    print()
    for k, v in summary.items():
        print(f"{k}: {v}")
    if args.plot and worst_map is not None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        seed, err, err_phys, err_nom = worst_map
        labels = (
            (err_nom, "uncalibrated, with quantisation"),
            (err, "calibrated, no quantisation"),
            (err_phys, "calibrated, with quantisation"),
        )
        fig, axes = plt.subplots(3, 4, figsize=(17, 10.5), sharex=True, sharey=True)
        for k, d in enumerate(DOF):
            vmax = max(float(err[:, k].max()), float(err_phys[:, k].max()))  # calibrated rows share a colour scale
            for row_i, (e, lab) in enumerate(labels):
                ax = axes[row_i, k]
                lim = {} if row_i == 0 else {"vmin": 0.0, "vmax": vmax}
                sca = ax.scatter(1e3 * check[:, 0], 1e3 * check[:, 1], c=e[:, k], s=14, cmap="viridis", **lim)
                fig.colorbar(sca, ax=ax, label=f"|{d} error| [{'mm' if k < 2 else 'mrad'}]")
                ax.set_title(f"{lab}: {d}\np95 {np.percentile(e[:, k], 95):.2f} (target {TARGET[k]:g})", fontsize=9)
                ax.set_xlabel("x [mm]")
                ax.set_ylabel("z [mm]")
        fig.suptitle(
            f"pose error over {len(check)} random workspace poses, worst twin with quantisation (seed {seed}); "
            "with quantisation = whole counts, piston anywhere in its count, play from a random side"
        )
        fig.tight_layout()
        fig.savefig(args.plot, dpi=80)
        print(f"wrote {args.plot}")
    if args.json:
        for r in rows:
            for k, v in list(r.items()):
                if isinstance(v, np.ndarray):
                    r[k] = v.tolist()
        write_json(args.json, {"machine": machine_note(), "twins": rows, "summary": summary})


if __name__ == "__main__":
    main()
