"""Tracking bench: continuous control (track mode) in closed loop on the simulated rig, against the targets.

Everything runs in simulated time through :mod:`bridge.service.track_loop` (the real motion controller,
the real codec and CAN path, the identified hydraulics, the tractor's sensors over the bus).

Run: .venv/bin/python bench/tracking_bench.py [--only bode,guidance,levelling,levelling-inside,terrain,cost]
     [--json FILE] [--quick]

Figures and targets (the specification; a target is never weakened, a miss is reported with its number):

* **bode** — frequency response per DOF x, z, roll, pitch in the tractor frame: sine setpoints of
  10 mm / 10 mrad amplitude (with their velocity) at 0.02…2 Hz (log-spaced), gain and phase from the
  measured pose (least-squares sine at the drive frequency over whole cycles after settling); −3 dB
  bandwidth and the phase lag at 0.1 Hz; beside it the ideal follower's gain (``ideal_sine_gain``) and
  bandwidth (``ideal_bandwidth_hz``). Reported as the hardware allows (the sway limiters are slow: valve
  multiplier 0.2). Plot ``docs/tracking_bode.png``.
* **guidance** — side shift after a crop row: the row 20 mm RMS, band-limited within the measured x
  bandwidth (shortest wavelength = speed / bandwidth, longest 30 m), camera noise 5 mm RMS at 10 Hz; 4
  and 8 km/h. Lateral error of the implement against the *true* row, RMS and p95: track vs goto_stream vs
  the ideal follower (``ideal_follow`` on the true row). Targets: track RMS ≤ 1/3 of goto_stream and
  ≤ 1.5 × ideal. (Scale: GPS-guided side-shift hoes hold 9–28 mm cross-track standard deviation.)
  Side by side (``GUIDANCE_VARIANTS``): the α-β camera filter (``track``, ``goto_stream``: as before), the
  Kalman row estimator with the camera under the implement (``track_kalman``; ``_lead``: the model's
  prediction a lead ahead), and the camera on the tractor's front axle (``CAMERA_AHEAD_M`` = 3.9 m ahead of
  the implement, a preview): ``track_preview_lead`` and ``track_preview_plan`` (a preview plan within the
  follower's limits, also streamed as gotos: ``goto_stream_preview_plan``). goto_stream stays the baseline.
* **levelling** — the ``levelling`` scenario (tractor roll ±0.1 rad from side slopes at 0.02 and 0.2 Hz):
  implement roll relative to gravity, RMS and max, track vs hold. Targets: RMS ≤ 5 mrad wherever the
  demand is inside the workspace and the bandwidth (the "inside" samples: over the last second the
  demand stayed inside the roll workspace and within the follower's pose velocity and acceleration
  limits); track ≥ 5 × better than hold.
* **levelling-inside** — the same figures on the ``levelling-inside`` scenario (tractor roll ±0.05 rad at
  0.02 and 0.1 Hz: the demand inside the roll workspace and within the follower's limits), where the
  levelling targets can be judged: in ``levelling`` almost no sample is inside.
* **terrain** — the ``terrain`` scenario (ground ±50 mm at 7 m and 19 m wavelength, 8 km/h): height of T
  above the ground minus the working height, RMS, side by side (``JOB_VARIANTS``): ``track`` (frame ground,
  the implement's sensor, as before), ``track_preview_plan`` (a look-ahead ground sensor
  ``GROUND_SENSOR_AHEAD_M`` = 4.9 m ahead of the implement; the client's ground profile and a preview plan,
  frame tractor), hold (fixed z). Target: track ≤ 1/3 of hold.
* **floors** (levelling, terrain) — the ideal follower of the true demand with full preview within the DOF's
  rate limits (also with the track follower's subset limits), and the workspace bound (the demand's distance
  beyond the faces); the best follower errs by at least the larger (``floor_rms``).
* **cost** — one controller cycle with a live track session (online Ruckig, exact inverse, limit checks,
  the guard every 5th cycle, the state message, the CAN send), p50/p99 wall (``time.perf_counter``) and
  CPU (``time.process_time``) over ≥ 5000 cycles. Target p99 ≤ 1 ms. Beside it the track cycle alone
  (``TrackMotion.step`` and ``look_ahead``: the follower's step and the guard 1 s ahead every 5th cycle), p50/p99/max.

Every run also counts references outside the strokes and refused references (must be 0) and measured
samples outside the workspace beyond one count of every sensor (must be 0). Plots go to docs/tracking_*.png.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from _common import machine_note, write_json  # noqa: E402

from bridge.service.track_loop import LoopSettings, SimLoop, TrackLoopResult, run_track_loop  # noqa: E402
from bridge.sim.scenario import load_scenario, scenario_from_dict  # noqa: E402
from bridge.sim.terrain import LookAheadGroundSensor, TerrainTwin, TractorGeometry  # noqa: E402
from planner.model.kinematics import HitchModel  # noqa: E402
from planner.trajectory import MotionState  # noqa: E402
from planner.trajectory.ideal_follower import IdealFollower, ideal_bandwidth_hz, ideal_sine_gain  # noqa: E402
from planner.trajectory.track import TrackFollower  # noqa: E402

DOCS = Path(__file__).resolve().parent.parent / "docs"
DOFS = ("x", "z", "roll", "pitch")
AMPLITUDE = 0.01
FREQS = (0.02, 0.05, 0.1, 0.2, 0.3, 0.5, 0.7, 1.0, 1.4, 2.0)
FREQS_QUICK = (0.05, 0.1, 0.3, 0.7, 1.4)
SECTIONS = ("bode", "guidance", "levelling", "levelling-inside", "terrain", "cost")


def _verdict(ok: bool | None) -> str:
    return "n/a" if ok is None else ("met" if ok else "MISSED")


# -- bode ------------------------------------------------------------------------------------
def sine_response(model: HitchModel, dof: str, freqs: tuple[float, ...], quick: bool) -> list[dict]:
    """Gain and phase of the measured pose for sine setpoints of ``dof`` (one rig, one session)."""
    out = []
    d = DOFS.index(dof)
    with SimLoop(model, "flat") as loop:
        mc = loop.mc
        p0 = loop.measured_pose()
        session = mc.track_start("tractor", (dof,), 0.3).session
        seq = 0
        for f in freqs:
            w = 2 * math.pi * f
            settle = 3.0
            cycles = 1 if f < 0.1 else (2 if f < 0.5 else 4)
            fit_s = cycles / f
            t0 = loop.now_s
            ts, ys = [], []
            while loop.now_s < t0 + settle + fit_s - 1e-9:
                tau = loop.now_s - t0
                seq += 1
                mc.track_setpoint(
                    session,
                    seq,
                    {dof: float(p0[d] + AMPLITUDE * math.sin(w * tau))},
                    {dof: AMPLITUDE * w * math.cos(w * tau)},
                )
                loop.cycle()
                tau = loop.now_s - t0
                if tau >= settle - 1e-9:
                    ts.append(tau)
                    ys.append(loop.measured_pose()[d] - p0[d])
            tt = np.array(ts)
            A = np.column_stack([np.sin(w * tt), np.cos(w * tt), np.ones_like(tt)])
            (a, b, _), *_ = np.linalg.lstsq(A, np.array(ys), rcond=None)
            ideal = ideal_sine_gain(loop.planner, dof, AMPLITUDE, f, p0)
            out.append(
                {
                    "frequency_hz": f,
                    "gain": float(math.hypot(a, b) / AMPLITUDE),
                    "phase_deg": float(math.degrees(math.atan2(b, a))),
                    "ideal_gain": ideal.gain,
                    "ideal_limit": ideal.limit,
                }
            )
            if quick and out[-1]["gain"] < 0.2:
                break
        mc.track_stop(session)
    return out


def bandwidth(points: list[dict]) -> float | None:
    """The first −3 dB crossing (log-interpolated), None if the gain never fell below 1/√2."""
    r2 = 1 / math.sqrt(2)
    for p, q in zip(points, points[1:], strict=False):
        if p["gain"] >= r2 > q["gain"]:
            lf = math.log(p["frequency_hz"]) + (math.log(q["frequency_hz"]) - math.log(p["frequency_hz"])) * (
                p["gain"] - r2
            ) / (p["gain"] - q["gain"])
            return math.exp(lf)
    return None if points and points[0]["gain"] >= r2 else (points[0]["frequency_hz"] if points else None)


def bench_bode(model: HitchModel, quick: bool) -> dict:
    freqs = FREQS_QUICK if quick else FREQS
    res = {}
    for dof in DOFS:
        pts = sine_response(model, dof, freqs, quick)
        at01 = next((p for p in pts if abs(p["frequency_hz"] - 0.1) < 1e-9), None)
        with SimLoop(model, "flat") as loop:
            ideal_bw = ideal_bandwidth_hz(loop.planner, dof, AMPLITUDE, loop.measured_pose())
        res[dof] = {
            "points": pts,
            "bandwidth_hz": bandwidth(pts),
            "phase_lag_deg_at_0_1_hz": None if at01 is None else -at01["phase_deg"],
            "ideal_bandwidth_hz": ideal_bw,
        }
        print(
            f"bode {dof:5s}: -3 dB {res[dof]['bandwidth_hz']} Hz (ideal {ideal_bw:.3f} Hz), "
            f"lag at 0.1 Hz {res[dof]['phase_lag_deg_at_0_1_hz']} deg",
            flush=True,
        )
    _plot_bode(res)
    return res


def _plot_bode(res: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(2, 1, figsize=(9, 7), sharex=True, constrained_layout=True)
    for dof, r in res.items():
        f = [p["frequency_hz"] for p in r["points"]]
        (line,) = ax[0].semilogx(f, [20 * math.log10(max(p["gain"], 1e-6)) for p in r["points"]], "o-", label=dof)
        ax[0].semilogx(
            f, [20 * math.log10(max(p["ideal_gain"], 1e-6)) for p in r["points"]], "--", color=line.get_color(), lw=1
        )
        phase = np.degrees(np.unwrap(np.radians([p["phase_deg"] for p in r["points"]])))
        ax[1].semilogx(f, phase, "o-", color=line.get_color(), label=dof)
    ax[0].axhline(-3, color="grey", lw=0.8, ls=":")
    ax[0].set_ylabel("gain [dB] (dashed: ideal follower)")
    ax[0].set_title("track mode, 10 mm / 10 mrad sine setpoints, measured pose (simulated rig)")
    ax[1].set_ylabel("phase [deg]")
    ax[1].set_xlabel("frequency [Hz]")
    for a in ax:
        a.grid(alpha=0.3, which="both")
        a.legend(fontsize=8)
    fig.savefig(DOCS / "tracking_bode.png", dpi=90)
    plt.close(fig)


# -- guidance -------------------------------------------------------------------------------
#: the guidance camera on the tractor's front axle: wheelbase + implement behind the rear axle (the twin's
#: default tractor, 2.7 m + 1.2 m) ahead of the implement
CAMERA_AHEAD_M = TractorGeometry().wheelbase_m + TerrainTwin().implement_behind_m
#: guidance variants, side by side: (strategy, LoopSettings fields, camera look-ahead [m])
GUIDANCE_VARIANTS: dict[str, tuple[str, dict, float]] = {
    "track": ("track", {}, 0.0),  # the α-β camera filter, the row under the implement now (before)
    "goto_stream": ("goto_stream", {}, 0.0),  # the same setpoints as gotos (today's API: the baseline)
    "track_kalman": ("track", {"row_estimator": "kalman"}, 0.0),
    "track_kalman_lead": ("track", {"row_estimator": "kalman", "row_setpoint": "lead"}, 0.0),
    "track_preview_lead": ("track", {"row_estimator": "kalman", "row_setpoint": "lead"}, CAMERA_AHEAD_M),
    "track_preview_plan": ("track", {"row_estimator": "kalman", "row_setpoint": "plan"}, CAMERA_AHEAD_M),
    "goto_stream_preview_plan": ("goto_stream", {"row_estimator": "kalman", "row_setpoint": "plan"}, CAMERA_AHEAD_M),
}
GUIDANCE_PLOTTED = ("track", "goto_stream", "track_kalman", "track_preview_plan")


def _row_scenario(speed_m_s: float, f_max_hz: float, duration_s: float, camera_ahead_m: float = 0.0):
    lam_min = max(0.5, speed_m_s / f_max_hz)
    return scenario_from_dict(
        {
            "schema_version": 1,
            "name": f"guidance-{speed_m_s * 3.6:.0f}kmh",
            "duration_s": duration_s,
            "speed": {"constant_m_s": speed_m_s},
            "signals": {
                "row_offset_rms_m": 0.020,
                "row_wavelength_min_m": lam_min,
                "row_wavelength_max_m": max(30.0, lam_min),
                "row_noise_rms_m": 0.005,
                "row_rate_hz": 10.0,
                "row_camera_ahead_m": camera_ahead_m,
                "seed": 2024,
            },
        }
    )


def bench_guidance(
    model: HitchModel, quick: bool, x_bandwidth_hz: float | None, variants: tuple[str, ...] | None = None
) -> dict:
    """``variants``: a subset of :data:`GUIDANCE_VARIANTS` (``track`` and ``goto_stream`` always run: the
    ideal follower's time base and the baseline); None: all."""
    f_bw = x_bandwidth_hz if x_bandwidth_hz else 0.3
    duration = 30.0 if quick else 60.0
    out: dict = {"row_band_top_hz": f_bw}
    chosen = {
        k: v for k, v in GUIDANCE_VARIANTS.items() if variants is None or k in variants or k in ("track", "goto_stream")
    }
    for kmh in (4, 8):
        v = kmh / 3.6
        runs = {}
        for name, (strategy, fields, ahead) in chosen.items():
            sc = _row_scenario(v, f_bw, duration, ahead)
            runs[name] = run_track_loop(model, sc, LoopSettings(strategy=strategy, **fields))
        tr = runs["track"]
        ev = tr.evaluated
        with SimLoop(model, "flat") as loop:
            # tol 1e-6 m: the default 1e-9 runs out of OSQP iterations on 3000 samples
            ideal = IdealFollower(loop.planner, "x", loop.measured_pose(), tol=1e-6).follow(tr.t, tr.row)
        ideal_err = ideal.error[ev]
        res = {
            s: {"rms_m": r.figures.rms, "p95_m": r.figures.p95, "max_m": r.figures.max, "counts": r.counts}
            for s, r in runs.items()
        }
        res["ideal"] = {
            "rms_m": float(np.sqrt(np.mean(ideal_err**2))),
            "p95_m": float(np.percentile(np.abs(ideal_err), 95)),
        }
        res["row_rms_m"] = float(np.sqrt(np.mean(tr.row[ev] ** 2)))
        res["row_wavelength_min_m"] = max(0.5, v / f_bw)
        res["camera_ahead_m"] = CAMERA_AHEAD_M
        for name, r in runs.items():  # where the error is: the setpoint against the row, the reference against it
            e = r.evaluated & np.isfinite(r.setpoint)
            res[name]["setpoint_vs_row_rms_m"] = float(np.sqrt(np.mean((r.setpoint[e] - r.row[e]) ** 2)))
            e &= np.isfinite(r.reference[:, 0])
            res[name]["reference_vs_setpoint_rms_m"] = float(np.sqrt(np.mean((r.reference[e, 0] - r.setpoint[e]) ** 2)))
        out[f"{kmh}kmh"] = res
        _plot_runs(
            f"tracking_guidance_{kmh}kmh.png",
            {k: runs[k] for k in GUIDANCE_PLOTTED if k in runs},
            extra=("ideal", tr.t, ideal.x),
        )
        print(
            f"guidance {kmh} km/h: "
            + ", ".join(f"{k} {res[k]['rms_m'] * 1e3:.2f}" for k in chosen)
            + f", ideal {res['ideal']['rms_m'] * 1e3:.2f} mm RMS",
            flush=True,
        )
    return out


# -- levelling, terrain ----------------------------------------------------------------------
#: the look-ahead ground sensor for terrain following: on the tractor's front weight, 1 m ahead of the front
#: axle (wheelbase 2.7 m + implement 1.2 m behind the rear axle + 1 m) ahead of the implement
GROUND_SENSOR_AHEAD_M = TractorGeometry().wheelbase_m + TerrainTwin().implement_behind_m + 1.0
#: per job: variant -> (strategy, LoopSettings fields, look-ahead ground sensor [m] or 0)
JOB_VARIANTS: dict[str, dict[str, tuple[str, dict, float]]] = {
    "levelling": {"track": ("track", {}, 0.0), "hold": ("hold", {}, 0.0)},
    "levelling-inside": {"track": ("track", {}, 0.0), "hold": ("hold", {}, 0.0)},
    "terrain": {
        "track": ("track", {}, 0.0),  # frame ground: the implement's sensor, under it (as before)
        "track_preview_plan": ("track", {"ground_setpoint": "plan"}, GROUND_SENSOR_AHEAD_M),
        "hold": ("hold", {}, 0.0),
    },
}


def bench_job(model: HitchModel, scenario: str, quick: bool, duration_quick: float) -> dict:
    """The job's variants side by side, and the ideal follower (full preview of the true demand, the DOF's
    velocity, acceleration and jerk limits and its workspace range) as the physical floor."""
    sc = load_scenario(scenario)
    dur = duration_quick if quick else sc.duration_s
    runs = {}
    for name, (strategy, fields, ahead) in JOB_VARIANTS[scenario].items():
        sc_v = sc
        if ahead > 0:
            twin = dataclasses.replace(sc.twin, ground_sensor=LookAheadGroundSensor(ahead_m=ahead, seed=2024))
            sc_v = dataclasses.replace(sc, twin=twin)
        runs[name] = run_track_loop(model, sc_v, LoopSettings(strategy=strategy, duration_s=dur, **fields))
    tr = runs["track"]
    i = tr.dof_index
    with SimLoop(model, "flat") as loop:
        tp = loop.planner
        tol = 1e-6  # m or rad: the default 1e-9 runs out of OSQP iterations on thousands of samples
        lo_i, hi_i = float(tp.lo[i]), float(tp.hi[i])
        # the ideal follower within the DOF's rate limits (full preview), without the workspace: with the
        # workspace as constraints too OSQP does not converge on the levelling demand (mostly beyond the face)
        ideal = IdealFollower(tp, tr.dof, loop.measured_pose(), tol=tol)
        follow = ideal.follow(tr.t, tr.demand)
        # the same with the track follower's own limits (the subset limits: whole range, 5 % margin)
        sub = TrackFollower(tp, MotionState.at_rest(loop.measured_pose()), (tr.dof,), 0.3).limits
        ideal_sub = IdealFollower(tp, tr.dof, loop.measured_pose(), tol=tol)
        ideal_sub.limits = dataclasses.replace(
            ideal_sub.limits,
            velocity=float(sub.velocity[i]),
            acceleration=float(sub.acceleration[i]),
            jerk=float(sub.jerk[i]),
        )
        follow_sub = ideal_sub.follow(tr.t, tr.demand)
    ev = tr.evaluated
    # lower bounds of the best follower's error: no position inside the workspace is nearer the demand than
    # its clip (the workspace bound), and none within the rate limits nearer than the rate-limited ideal; the
    # best follower within both errs by at least the larger of the two
    clip_err = (np.clip(tr.demand, lo_i, hi_i) - tr.demand)[ev]
    ideal_err = (follow.x - tr.demand)[ev]
    sub_err = (follow_sub.x - tr.demand)[ev]

    def _fig(e: np.ndarray) -> dict:
        return {"rms": float(np.sqrt(np.mean(e**2))), "max": float(np.max(np.abs(e)))}

    _plot_runs(f"tracking_{scenario}.png", runs, extra=("ideal", tr.t, follow.x))
    out: dict = {}
    for s, r in runs.items():
        out[s] = {
            "error": r.figures.as_dict(),
            "error_inside": r.figures_inside.as_dict(),
            "inside_fraction": r.inside_fraction,
            "counts": r.counts,
            "workspace_excess": r.workspace_excess,
            "notes": list(r.notes),
        }
        e = r.evaluated & np.isfinite(r.setpoint)
        if r.strategy == "track" and r.frame == "tractor" and e.any():  # how far the setpoint is from the demand
            out[s]["setpoint_vs_demand_rms"] = float(np.sqrt(np.mean((r.setpoint[e] - r.demand[e]) ** 2)))
    out["ideal"] = {
        "error": _fig(ideal_err),
        "limits": {"velocity": ideal.limits.velocity, "acceleration": ideal.limits.acceleration},
    }
    out["ideal_subset_limits"] = {
        "error": _fig(sub_err),
        "limits": {"velocity": float(sub.velocity[i]), "acceleration": float(sub.acceleration[i])},
    }
    out["workspace_bound"] = {"error": _fig(clip_err), "workspace": [lo_i, hi_i]}
    out["floor_rms"] = max(out["ideal"]["error"]["rms"], out["workspace_bound"]["error"]["rms"])
    if any(ahead > 0 for _, _, ahead in JOB_VARIANTS[scenario].values()):
        out["ground_sensor_ahead_m"] = GROUND_SENSOR_AHEAD_M
    print(
        f"{scenario}: "
        + ", ".join(f"{k} RMS {r.figures.rms:.5f}" for k, r in runs.items())
        + f", ideal RMS {out['ideal']['error']['rms']:.5f} (track inside {tr.figures_inside.rms:.5f}, "
        f"{100 * tr.inside_fraction:.0f} %)",
        flush=True,
    )
    return out


def _plot_runs(name: str, runs: dict[str, TrackLoopResult], extra: tuple | None = None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    first = next(iter(runs.values()))
    d = first.dof_index
    unit = "mm" if first.dof in ("x", "z") else "mrad"
    fig, ax = plt.subplots(2, 1, figsize=(12, 7), sharex=True, constrained_layout=True)
    ax[0].plot(first.t, first.demand * 1e3, color="k", lw=1.2, label="demand (zero error)")
    if first.frame == "tractor" and first.job == "guidance":
        ax[0].plot(first.t, first.setpoint * 1e3, color="grey", lw=0.6, alpha=0.7, label="setpoint (filtered camera)")
    for s, r in runs.items():
        (line,) = ax[0].plot(r.t, r.reference[:, d] * 1e3, "--", lw=0.8, label=f"{s} reference")
        ax[0].plot(r.t, r.truth[:, d] * 1e3, color=line.get_color(), lw=1, label=f"{s} truth")
        ax[1].plot(r.t, r.error * 1e3, color=line.get_color(), lw=0.9, label=f"{s}: RMS {r.figures.rms * 1e3:.2f}")
    if extra is not None:
        label, t, x = extra
        ax[0].plot(t, x * 1e3, ":", color="m", lw=1, label=f"{label} follower")
        e = (x - (first.row if first.job == "guidance" else first.demand)) * 1e3
        ax[1].plot(t, e, ":", color="m", lw=0.9, label=f"{label}: RMS {np.sqrt(np.mean(e[first.evaluated] ** 2)):.2f}")
    ax[0].set_ylabel(f"{first.dof} [{unit}], tractor frame")
    ax[0].set_title(f"{first.scenario}: {first.job}")
    ax[1].set_ylabel(f"{first.job} error [{unit}]")
    ax[1].set_xlabel("scenario time since the loop started [s]")
    for a in ax:
        a.grid(alpha=0.3)
        a.legend(fontsize=7, loc="upper right", ncol=2)
    fig.savefig(DOCS / name, dpi=90)
    plt.close(fig)


# -- cost -----------------------------------------------------------------------------------
def bench_cost(model: HitchModel, cycles: int) -> dict:
    sink: list[tuple[float, float]] = []

    def grab(loop: SimLoop) -> None:
        if loop.cycle_times is None:
            loop.cycle_times = sink

    from bridge.service.motion import types as motion_types

    track: list[float] = []  # per cycle: the step plus the guard's look-ahead after the send
    step, look_ahead = motion_types.TrackMotion.step, motion_types.TrackMotion.look_ahead

    def timed(self, guard, now):  # type: ignore[no-untyped-def]
        t0 = time.perf_counter()
        out = step(self, guard, now)
        track.append(time.perf_counter() - t0)
        return out

    def timed_look_ahead(self, guard):  # type: ignore[no-untyped-def]
        t0 = time.perf_counter()
        look_ahead(self, guard)
        track[-1] += time.perf_counter() - t0  # the same cycle's step came first

    duration = 0.5 + 0.02 + 1.0 + cycles * 0.02
    sc = load_scenario("levelling")
    motion_types.TrackMotion.step = timed  # type: ignore[method-assign]
    motion_types.TrackMotion.look_ahead = timed_look_ahead  # type: ignore[method-assign]
    try:
        run_track_loop(
            model, sc, LoopSettings(strategy="track", duration_s=min(duration, 3600.0), settle_s=1.0), on_cycle=grab
        )
    finally:
        motion_types.TrackMotion.step = step  # type: ignore[method-assign]
        motion_types.TrackMotion.look_ahead = look_ahead  # type: ignore[method-assign]
    a = np.array(sink[:cycles]) * 1e6
    b = np.array(track[-cycles:]) * 1e6
    return {
        "track_cycles": int(len(b)),
        "track_p50_us": float(np.percentile(b, 50)),
        "track_p99_us": float(np.percentile(b, 99)),
        "track_max_us": float(b.max()),
        "cycles": int(len(a)),
        "wall_p50_us": float(np.percentile(a[:, 0], 50)),
        "wall_p99_us": float(np.percentile(a[:, 0], 99)),
        "wall_max_us": float(a[:, 0].max()),
        "cpu_p50_us": float(np.percentile(a[:, 1], 50)),
        "cpu_p99_us": float(np.percentile(a[:, 1], 99)),
    }


# -- table ----------------------------------------------------------------------------------
def _levelling_rows(sec: str, lv: dict) -> list[tuple[str, str, str, str]]:
    """The table rows of one levelling scenario (``sec``: its section name)."""
    rows: list[tuple[str, str, str, str]] = []
    ti, th = lv["track"]["error_inside"], lv["hold"]["error_inside"]
    rows.append(
        (
            f"{sec}: roll error inside ({100 * lv['track']['inside_fraction']:.0f} % of samples), RMS / max",
            f"{ti['rms'] * 1e3:.2f} / {ti['max'] * 1e3:.2f} mrad",
            "RMS ≤ 5 mrad",
            _verdict(ti["rms"] <= 5e-3) if ti["n"] else "n/a (no sample inside)",
        )
    )
    ta, ha = lv["track"]["error"], lv["hold"]["error"]
    rows.append(
        (
            f"{sec}: roll error all samples, RMS / max, track vs hold",
            f"{ta['rms'] * 1e3:.2f} / {ta['max'] * 1e3:.2f} vs {ha['rms'] * 1e3:.2f} / {ha['max'] * 1e3:.2f} mrad",
            "track ≤ hold / 5",
            _verdict(ta["rms"] <= ha["rms"] / 5),
        )
    )
    hold = ha["rms"]
    for key, what in (("ideal", "actuator limits at the pose"), ("ideal_subset_limits", "the follower's limits")):
        li, lim = lv[key]["error"], lv[key]["limits"]
        rows.append(
            (
                f"{sec}: ideal follower (full preview, {what} {lim['velocity'] * 1e3:.1f} mrad/s, "
                f"{lim['acceleration'] * 1e3:.0f} mrad/s², no workspace), RMS / max",
                f"{li['rms'] * 1e3:.2f} / {li['max'] * 1e3:.2f} mrad",
                "report",
                "n/a",
            )
        )
    wb = lv["workspace_bound"]["error"]
    rows.append(
        (
            f"{sec}: workspace bound (the demand's distance beyond the roll faces), RMS / max",
            f"{wb['rms'] * 1e3:.2f} / {wb['max'] * 1e3:.2f} mrad",
            "report",
            "n/a",
        )
    )
    fl = lv["floor_rms"]
    rows.append(
        (
            f"{sec}: floor = max(ideal, workspace bound) RMS; hold / floor",
            (
                f"{fl * 1e3:.2f} mrad; hold / floor = {hold / fl:.2f} (at most this much better than hold)"
                if fl > 1e-6
                else f"{fl * 1e3:.4f} mrad (≈ 0: any ratio possible)"
            ),
            "5 × better possible? (hold / floor ≥ 5)",
            "possible?" if fl <= 1e-6 or hold / fl >= 5 else "NOT possible",
        )
    )
    if ti["n"] and th["n"]:
        rows.append(
            (
                f"{sec}: inside samples, track vs hold RMS",
                f"{ti['rms'] * 1e3:.2f} vs {th['rms'] * 1e3:.2f} mrad",
                "track ≤ hold / 5",
                _verdict(ti["rms"] <= th["rms"] / 5),
            )
        )
    return rows


def table(res: dict) -> list[tuple[str, str, str, str]]:
    rows: list[tuple[str, str, str, str]] = []
    if "bode" in res:
        for dof, r in res["bode"].items():
            u = "Hz"
            bw = r["bandwidth_hz"]
            rows.append(
                (
                    f"bandwidth {dof} (−3 dB, 10 {'mm' if dof in ('x', 'z') else 'mrad'})",
                    f"{bw:.3f} {u}" if bw else "> top frequency",
                    f"report (ideal {r['ideal_bandwidth_hz']:.3f} Hz)",
                    "n/a",
                )
            )
            lag = r["phase_lag_deg_at_0_1_hz"]
            rows.append((f"phase lag {dof} at 0.1 Hz", "n/a" if lag is None else f"{lag:.1f} deg", "report", "n/a"))
    if "guidance" in res:
        for k in ("4kmh", "8kmh"):
            g = res["guidance"][k]
            gs, idl = g["goto_stream"]["rms_m"], g["ideal"]["rms_m"]
            rows.append(
                (
                    f"guidance {k}: lateral RMS (p95) goto_stream (baseline) / ideal",
                    f"{gs * 1e3:.2f} ({g['goto_stream']['p95_m'] * 1e3:.2f}) / {idl * 1e3:.2f} mm",
                    "report",
                    "n/a",
                )
            )
            for name in GUIDANCE_VARIANTS:
                if name == "goto_stream" or name not in g:
                    continue
                tr = g[name]["rms_m"]
                sp_row = g[name].get("setpoint_vs_row_rms_m", math.nan) * 1e3
                ref_sp = g[name].get("reference_vs_setpoint_rms_m", math.nan) * 1e3
                rows.append(
                    (
                        f"guidance {k}: {name}: lateral RMS (p95); setpoint−row, reference−setpoint RMS",
                        f"{tr * 1e3:.2f} ({g[name]['p95_m'] * 1e3:.2f}) mm = {gs / tr:.2f} × better than "
                        f"goto_stream, {tr / idl:.2f} × ideal; {sp_row:.1f}, {ref_sp:.1f} mm",
                        "≤ goto_stream / 3 and ≤ 1.5 × ideal",
                        _verdict(tr <= gs / 3 and tr <= 1.5 * idl),
                    )
                )
    for sec in ("levelling", "levelling-inside"):
        if sec in res:
            rows += _levelling_rows(sec, res[sec])
    if "terrain" in res:
        te = res["terrain"]
        b, idl = te["hold"]["error"]["rms"], te["floor_rms"]
        isub = te["ideal_subset_limits"]
        rows.append(
            (
                f"terrain: ideal with the follower's limits ({isub['limits']['velocity'] * 1e3:.1f} mm/s, "
                f"{isub['limits']['acceleration'] * 1e3:.0f} mm/s²), RMS / max",
                f"{isub['error']['rms'] * 1e3:.3f} / {isub['error']['max'] * 1e3:.3f} mm",
                "report",
                "n/a",
            )
        )
        rows.append(
            (
                "terrain: height error RMS, hold / floor (ideal: full preview, z limits; workspace bound)",
                f"{b * 1e3:.2f} / {idl * 1e3:.3f} mm",
                "report",
                "n/a",
            )
        )
        for name in JOB_VARIANTS["terrain"]:
            if name == "hold" or name not in te:
                continue
            a = te[name]["error"]["rms"]
            sp_d = te[name].get("setpoint_vs_demand_rms")
            rows.append(
                (
                    f"terrain: {name}: height error RMS (p95)" + ("; setpoint−demand RMS" if sp_d else ""),
                    f"{a * 1e3:.2f} ({te[name]['error']['p95'] * 1e3:.2f}) mm = {b / a:.2f} × better than hold, "
                    + (f"{a / idl:.2f} × ideal" if idl > 1e-5 else "ideal ≈ 0")
                    + (f"; {sp_d * 1e3:.1f} mm" if sp_d else ""),
                    "track ≤ hold / 3",
                    _verdict(a <= b / 3),
                )
            )
    if "cost" in res:
        c = res["cost"]
        rows.append(
            (
                f"cost: controller cycle with a live session, p50 / p99 ({c['cycles']} cycles)",
                f"wall {c['wall_p50_us']:.0f} / {c['wall_p99_us']:.0f} µs; CPU {c['cpu_p50_us']:.0f} / "
                f"{c['cpu_p99_us']:.0f} µs",
                "p99 ≤ 1 ms",
                _verdict(c["wall_p99_us"] <= 1000.0),
            )
        )
        if "track_p99_us" in c:
            rows.append(
                (
                    f"cost: track cycle (follower step + guard 1/5), p50 / p99 / max ({c['track_cycles']} cycles)",
                    f"wall {c['track_p50_us']:.0f} / {c['track_p99_us']:.0f} / {c['track_max_us']:.0f} µs",
                    "p99 ≤ 1 ms",
                    _verdict(c["track_p99_us"] <= 1000.0),
                )
            )
    counts = [
        (name, r)
        for sec in ("levelling", "levelling-inside", "terrain")
        if sec in res
        for name, r in ((f"{sec} {s}", res[sec][s]) for s in JOB_VARIANTS[sec])
    ]
    if "guidance" in res:
        counts += [
            (f"guidance {k} {s}", res["guidance"][k][s])
            for k in ("4kmh", "8kmh")
            for s in GUIDANCE_VARIANTS
            if s in res["guidance"][k]
        ]
    if counts:
        bad = sum(c["counts"]["references_outside_strokes"] + c["counts"]["refused"] for _, c in counts)
        out = sum(c["counts"]["outside_workspace"] for _, c in counts)
        rows.append(("references outside the strokes + refused (all runs)", str(bad), "0", _verdict(bad == 0)))
        rows.append(("measured samples outside the workspace > 1 count (all runs)", str(out), "0", _verdict(out == 0)))
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default=",".join(SECTIONS), help=f"comma-separated subset of {','.join(SECTIONS)}")
    ap.add_argument("--json", default=None, help="write the results as JSON")
    ap.add_argument("--quick", action="store_true", help="fewer frequencies, shorter runs")
    ap.add_argument("--x-bandwidth-hz", type=float, default=None, help="guidance without bode: the x bandwidth [Hz]")
    ap.add_argument(
        "--variants",
        default=None,
        help=f"guidance: comma-separated subset of {','.join(GUIDANCE_VARIANTS)} (track, goto_stream always run)",
    )
    args = ap.parse_args()
    only = [s.strip() for s in args.only.split(",") if s.strip()]
    bad = [s for s in only if s not in SECTIONS]
    if bad:
        ap.error(f"--only: unknown section(s) {', '.join(bad)}; allowed {', '.join(SECTIONS)}")
    model = HitchModel.from_profile("thesis-t132", "2")
    t0 = time.perf_counter()
    res: dict = {"machine": machine_note(), "load": os.getloadavg(), "quick": args.quick}
    if "bode" in only:
        res["bode"] = bench_bode(model, args.quick)
    if "guidance" in only:
        bw = res.get("bode", {}).get("x", {}).get("bandwidth_hz") or args.x_bandwidth_hz
        variants = None if args.variants is None else tuple(v.strip() for v in args.variants.split(",") if v.strip())
        unknown = [v for v in variants or () if v not in GUIDANCE_VARIANTS]
        if unknown:
            ap.error(f"--variants: unknown {', '.join(unknown)}; allowed {', '.join(GUIDANCE_VARIANTS)}")
        res["guidance"] = bench_guidance(model, args.quick, bw, variants)
    for sec in ("levelling", "levelling-inside"):
        if sec in only:
            res[sec] = bench_job(model, sec, args.quick, 60.0)
    if "terrain" in only:
        res["terrain"] = bench_job(model, "terrain", args.quick, 40.0)
    if "cost" in only:
        res["cost"] = bench_cost(model, 1000 if args.quick else 5000)
    write_json(args.json, res)  # the figures first: a table bug must not lose them
    res["table"] = table(res)
    res["wall_s"] = time.perf_counter() - t0
    print("\n| figure | measured | target | verdict |\n|---|---|---|---|")
    for row in res["table"]:
        print("| " + " | ".join(row) + " |")
    print(f"\nload average {res['load']}, {res['wall_s']:.0f} s wall")
    write_json(args.json, res)
    return 0


if __name__ == "__main__":
    sys.exit(main())
