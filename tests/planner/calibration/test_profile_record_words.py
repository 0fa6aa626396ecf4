"""The words of a calibrated profile's record: its description and each parameter's status.

Truth: the thresholds the module documents (solve: a share below 1e-6 is kept nominal, below one half mostly
its tape error, below 99.5 % partly identified) and the thesis profile's own description text.
"""

from __future__ import annotations

import math

import pytest

from planner.calibration.accuracy import THESIS_ACCURACY
from planner.calibration.profile_out import calibrated_description
from planner.calibration.solve import identification_status
from planner.profiles.hitch import load_profile


@pytest.mark.parametrize(
    ("share", "words"),
    [
        (0.0, "not identified"),
        (5e-7, "not identified"),
        (math.nan, "not identified"),
        (2e-6, "weakly identified"),
        (0.49, "weakly identified"),
        (0.5, "partly identified"),
        (0.99, "partly identified"),
        (0.995, "identified"),
        (1.0, "identified"),
    ],
)
def test_each_share_has_one_status(share, words):
    assert identification_status(share) == words


def test_a_calibrated_description_keeps_the_user_s_text_drops_tape_measured_and_names_day_and_poses():
    nominal = load_profile("thesis-t132").description
    assert nominal.endswith("(tape-measured)")
    once = calibrated_description(nominal, "2026-12-07T02:49:44+00:00", 20)
    assert once == (
        "Valtra T132 advanced rear hitch, geometry of thesis table 3-5; calibrated 2026-12-07 from 20 poses "
        "(hitch calibrate geometry)"
    )
    # calibrated again: the earlier note replaced, not stacked
    assert calibrated_description(once, "2027-01-02", 1) == (
        "Valtra T132 advanced rear hitch, geometry of thesis table 3-5; calibrated 2027-01-02 from 1 pose "
        "(hitch calibrate geometry)"
    )
    bare = calibrated_description("", "2027-01-02", 8)
    assert bare == "Calibrated 2027-01-02 from 8 poses (hitch calibrate geometry)"


def test_the_thesis_rows_have_no_count_of_poses():
    """The thesis's tables 3-8 … 3-10 give no count: None (JSON null), where 0 read as "no measurements"."""
    for rows in THESIS_ACCURACY.values():
        for st in rows.values():
            assert st.n is None and st.as_dict()["n"] is None
