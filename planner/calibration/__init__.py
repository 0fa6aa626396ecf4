"""Geometry calibration: identify a hitch's uncertain geometry (and AD map) from measured poses.

:mod:`~planner.calibration.parameters` (the uncertain parameters and their tape-size scales),
:mod:`~planner.calibration.parametric` (forward kinematics as a CasADi function of readings and
parameters), :mod:`~planner.calibration.solve` (Levenberg–Marquardt, identifiability, standard
deviations), :mod:`~planner.calibration.design` (D-optimal poses to measure),
:mod:`~planner.calibration.measurements` (the CSV measurement file),
:mod:`~planner.calibration.profile_out` (the calibrated profile with provenance),
:mod:`~planner.calibration.predicted` (the pose accuracy a calibration predicts) and
:mod:`~planner.calibration.accuracy` (the thesis's accuracy test). Names load lazily.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from planner.lazy import lazy_exports

if TYPE_CHECKING:
    from planner.calibration.accuracy import (
        THESIS_ACCURACY,
        AccuracyError,
        AccuracyPose,
        Deflections,
        DofStatistics,
        accuracy_statistics,
        thesis_sequence,
    )
    from planner.calibration.design import PoseDesign, candidate_poses, information_log_det, plan_poses
    from planner.calibration.measurements import (
        MeasurementSet,
        load_measurements,
        measurements_csv,
        parse_measurements,
    )
    from planner.calibration.parameters import CalibrationError, Parameter, ParameterSet
    from planner.calibration.parametric import OUTPUT_NAMES, ParametricModel
    from planner.calibration.predicted import (
        PredictedAccuracy,
        calibrated_covariance,
        predict_accuracy,
        tape_covariance,
    )
    from planner.calibration.profile_out import (
        calibrated_profile_toml,
        read_calibration_provenance,
        write_calibrated_profile,
    )
    from planner.calibration.solve import (
        CalibrationProblem,
        CalibrationResult,
        build_calibration_problem,
        identifiable_basis,
        solve_calibration,
    )

_SOURCES: dict[str, str] = {
    **dict.fromkeys(
        (
            "THESIS_ACCURACY",
            "AccuracyError",
            "AccuracyPose",
            "Deflections",
            "DofStatistics",
            "accuracy_statistics",
            "thesis_sequence",
        ),
        "planner.calibration.accuracy",
    ),
    **dict.fromkeys(
        ("PoseDesign", "candidate_poses", "information_log_det", "plan_poses"), "planner.calibration.design"
    ),
    **dict.fromkeys(
        ("MeasurementSet", "load_measurements", "measurements_csv", "parse_measurements"),
        "planner.calibration.measurements",
    ),
    **dict.fromkeys(("CalibrationError", "Parameter", "ParameterSet"), "planner.calibration.parameters"),
    **dict.fromkeys(("OUTPUT_NAMES", "ParametricModel"), "planner.calibration.parametric"),
    **dict.fromkeys(
        ("PredictedAccuracy", "calibrated_covariance", "predict_accuracy", "tape_covariance"),
        "planner.calibration.predicted",
    ),
    **dict.fromkeys(
        ("calibrated_profile_toml", "read_calibration_provenance", "write_calibrated_profile"),
        "planner.calibration.profile_out",
    ),
    **dict.fromkeys(
        (
            "CalibrationProblem",
            "CalibrationResult",
            "build_calibration_problem",
            "identifiable_basis",
            "solve_calibration",
        ),
        "planner.calibration.solve",
    ),
}

__all__ = [
    "THESIS_ACCURACY",
    "AccuracyError",
    "AccuracyPose",
    "Deflections",
    "DofStatistics",
    "accuracy_statistics",
    "thesis_sequence",
    "OUTPUT_NAMES",
    "CalibrationError",
    "CalibrationProblem",
    "CalibrationResult",
    "MeasurementSet",
    "Parameter",
    "ParameterSet",
    "ParametricModel",
    "PoseDesign",
    "PredictedAccuracy",
    "build_calibration_problem",
    "calibrated_covariance",
    "calibrated_profile_toml",
    "candidate_poses",
    "identifiable_basis",
    "information_log_det",
    "load_measurements",
    "measurements_csv",
    "parse_measurements",
    "plan_poses",
    "predict_accuracy",
    "read_calibration_provenance",
    "solve_calibration",
    "tape_covariance",
    "write_calibrated_profile",
]

if not TYPE_CHECKING:
    __getattr__, __dir__ = lazy_exports("planner.calibration", globals(), _SOURCES)
