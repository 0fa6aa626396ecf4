"""The implement a service starts with (docs/implements.md, *At start*), from a user trial (a tractor engineer):

* an implement of another ISO 730 category named at start (a tractor profile record not stored yet) went into every
  guard unchecked — the guards were built with the config's implement, and the category check of the start looked
  at stored implements only;
* ``--implement`` was ignored once a selection was persisted (the flag comes first now, then the persisted
  selection, then the config file's implement);
* an implement dropped at start (another category, not defined) was not said anywhere.

Tested where the choice is made (:class:`~bridge.service.implements.ImplementService`, through ``ServiceAPI`` on the
simulated rig, and :func:`~bridge.service.config.load_service_config`) and on a started service: the guards, the
``config`` reply and the start-up warnings (``hitch serve`` prints them and the black box's ``started`` record
keeps them)."""

from __future__ import annotations

from typing import Any

import pytest

from bridge.service.config import ServiceConfig, ServiceConfigError, load_service_config
from bridge.service.implements import SELECTED_SETTING, ImplementService
from bridge.service.server import HitchService
from bridge.service.store import HitchStore, StoredImplement, StoreError
from planner.errors import HitchError
from planner.limits.implement_limits import ImplementLimits
from tests.helpers import SimService, wait_until

HARROW = {"name": "harrow", "category": "2", "mass_kg": 1200.0, "com_m": [0.0, 0.6, 0.4], "upper_height_m": 0.28}
CAT2 = "cat2-power-harrow-1500"  # a category-2 record of tractor-6t (the thesis profile's tractor)
SPREADER = "cat2-spreader-400"  # another one (400 kg)
SELECT = "Change it with `hitch implement select NAME`"
TAIL = f"{SELECT} (persisted; `default` selects none)"
NOT_DEFINED = "it is not defined (neither stored nor a record of the tractor profile)"
CAT2_ON_3 = "it is an ISO 730 category 2 implement, this hitch category 3"


class _Motion:
    """What restore needs of the controller: the implements it is given."""

    def __init__(self) -> None:
        self.selected: list[tuple[Any, ImplementLimits]] = []

    def select_implement(self, implement: Any, limits: ImplementLimits, *, announce: bool = True) -> dict[str, Any]:
        self.selected.append((implement, limits))
        return {}


def _restored(store: HitchStore, **kw: Any) -> tuple[ImplementService, _Motion, list[Any]]:
    motion, planning = _Motion(), []
    svc = ImplementService(store, motion, tractor_profile="tractor-6t", **kw)  # type: ignore[arg-type]
    svc.on_applied = lambda record, limits: planning.append(record)
    svc.restore()
    return svc, motion, planning


def test_a_profile_implement_of_another_category_named_at_start_is_not_taken_and_said(tmp_path):
    """The trial: ``implement = "cat2-power-harrow-1500"`` on a category-3 hitch started without a word and the
    guard used it (front_axle_share 0.309 against 0.506). It is not taken: the controller and the planning are given
    nothing (their guards are built without an implement: the started services below), and the start says which
    and why."""
    store = HitchStore(tmp_path / "hitch.sqlite3")
    svc, motion, planning = _restored(store, selected=CAT2, category="3")
    assert motion.selected == [] and planning == []
    assert svc.selected == "default" and svc.list()["selected"] == "default"
    assert svc.warnings == [
        f"implement: no implement is selected; not taken: {CAT2!r} (the config file's implement: it is an ISO 730 "
        f"category 2 implement, this hitch category 3). {SELECT} (persisted; `default` selects none)"
    ]
    # of the hitch's category: taken, its record (no limits: a profile record), nothing said
    svc, motion, planning = _restored(store, selected=CAT2, category="2")
    assert [r.name for r, _ in motion.selected] == [CAT2] and motion.selected[0][0].mass == 1500.0
    assert planning[0].name == CAT2 and svc.selected == CAT2 and svc.warnings == []


def test_a_persisted_implement_that_is_no_longer_defined_is_said(tmp_path):
    store = HitchStore(tmp_path / "hitch.sqlite3")
    store.set_setting(SELECTED_SETTING, "gone")
    svc, motion, _ = _restored(store, category="2")
    assert motion.selected == [] and svc.selected == "default"
    assert len(svc.warnings) == 1 and svc.warnings[0].startswith(
        "implement: no implement is selected; not taken: 'gone' (the persisted selection: it is not defined"
    )


@pytest.fixture
def path(model, tmp_path):
    """A store whose persisted selection is the stored category-2 implement ``harrow`` (selected, then closed)."""
    path = tmp_path / "hitch.sqlite3"
    first = SimService(model, path)
    try:
        first.ok("implements/define", HARROW)
        first.ok("implements/select", {"name": "harrow"})
    finally:
        first.close()
    return path


def test_the_implement_flag_comes_before_the_persisted_selection(model, path):
    """The trial: ``hitch serve --implement X`` ran with the persisted selection, silently. The flag's implement is
    selected (not persisted: a start without the flag selects the persisted one again), and the start says so."""
    svc = SimService(model, path, implement="cat2-spreader-400", implement_source="flag")
    try:
        assert svc.ok("implements/list")["selected"] == "cat2-spreader-400" and svc.api.implement == "cat2-spreader-400"
        for g in (svc.mc.guard, svc.mc.plan_guard):
            assert g.implement.name == "cat2-spreader-400" and g.implement.mass == 400.0
            assert g.implement_limits.upper_height_m is None  # a profile record has none (harrow's 0.28 is not kept)
        assert svc.ok("config")["implement"] == "cat2-spreader-400"
        assert svc.api.implements.warnings == [
            "implement: 'cat2-spreader-400' (--implement) is selected; not taken: 'harrow' (the persisted selection: "
            f"--implement comes first; a start without it selects 'harrow' again). {SELECT} (persisted; `default` "
            "selects none)"
        ]
        assert svc.store.get_setting(SELECTED_SETTING) == "harrow"
    finally:
        svc.close()


def test_the_persisted_selection_comes_before_the_config_file_s_implement_and_the_start_says_so(model, path):
    svc = SimService(model, path, implement="cat2-spreader-400")  # the file's (implement_source "file")
    try:
        assert svc.ok("implements/list")["selected"] == "harrow" and svc.mc.guard.implement.mass == 1200.0
        assert svc.mc.guard.implement_limits.upper_height_m == 0.28
        assert svc.api.implements.warnings == [
            "implement: 'harrow' (the persisted selection) is selected; not taken: 'cat2-spreader-400' (the config "
            f"file's implement: the persisted selection comes before it). {SELECT} (persisted; `default` selects none)"
        ]
    finally:
        svc.close()
    svc = SimService(model, path, implement="harrow", implement_source="flag")  # the same one: nothing to say
    try:
        assert svc.ok("implements/list")["selected"] == "harrow" and svc.api.implements.warnings == []
    finally:
        svc.close()


def test_the_config_says_whether_the_implement_came_from_the_flag_or_the_file(tmp_path):
    f = tmp_path / "svc.toml"
    f.write_text('[hitch]\nimplement = "cat2-spreader-400"\n')
    assert load_service_config(f).implement_source == "file"
    c = load_service_config(f, implement="cat2-power-harrow-1500")  # hitch serve --implement
    assert (c.implement, c.implement_source) == ("cat2-power-harrow-1500", "flag")
    assert load_service_config(None, implement="cat2-spreader-400").implement_source == "flag"
    assert load_service_config(f, implement=None).implement_source == "file"  # a flag not given
    assert ServiceConfig(implement="cat2-spreader-400").implement_source == "file"  # a program's own config
    f.write_text('[hitch]\nimplement_source = "flag"\n')  # not a key of the file
    with pytest.raises(ServiceConfigError, match="unknown key hitch.implement_source"):
        load_service_config(f)


def test_a_started_service_runs_without_an_implement_of_another_category_and_says_so(tmp_path):
    """The trial on a started service (the control core in the service's threads; no listener: no port): the
    guards were built with the config's category-2 implement on the category-3 hitch; ``config`` named it and the
    start-up warnings (printed by ``hitch serve``, the black box's ``started`` record) were empty."""
    cfg = ServiceConfig(
        listen=[], category="3", implement=CAT2, control_core="thread", planning_processes=0, data_dir=tmp_path
    )
    svc = HitchService(cfg).start()
    try:
        assert svc.motion is not None
        for g in (svc.motion.guard, svc.motion.plan_guard):
            assert g.implement is None
        ok, config = svc.api.handle("config", b"{}")
        assert ok and config["category"] == "3" and config["implement"] is None, config
        line = [w for w in svc.warnings if w.startswith("implement: ")]
        assert line and f"not taken: {CAT2!r} (the config file's implement: it is an ISO 730 category 2" in line[0]
    finally:
        svc.close()


@pytest.mark.slow
def test_the_control_core_in_its_own_process_and_the_planning_process_get_no_implement_of_another_category(tmp_path):
    """As above with the control core in its own process and a planning process (the defaults, as ``hitch serve``
    runs): the stability the core reports is the hitch's without an implement."""

    def share(implement: str | None, where: str) -> float:
        cfg = ServiceConfig(
            listen=[], category="3", implement=implement, planning_processes=1, data_dir=tmp_path / where
        )
        svc = HitchService(cfg).start()
        try:
            assert svc.core is not None
            assert wait_until(lambda: ((svc.latest_state or {}).get("stability") or {}).get("front_axle_share"))
            ok, config = svc.api.handle("config", b"{}")
            assert ok and config["implement"] is None, config
            if implement is not None:
                assert any(f"not taken: {implement!r}" in w for w in svc.warnings), svc.warnings
            ok, preview = svc.api.handle("plan", b'{"goal": {"z": 0.1}}')
            assert ok and preview["ok"], preview
            return float(svc.latest_state["stability"]["front_axle_share"])
        finally:
            svc.close()

    assert share(CAT2, "a") == pytest.approx(share(None, "b"), abs=1e-6)


# ---------------------------------------------------------------- a review of the precedence: fall through to the next


def _plough3(store: HitchStore) -> None:
    """A stored category-3 implement ``plough3``, persisted as the selection."""
    store.save_implement(StoredImplement("plough3", "3", 900.0, (0.0, 0.8, 0.3), ImplementLimits(upper_height_m=0.3)))
    store.set_setting(SELECTED_SETTING, "plough3")


def test_a_persisted_selection_no_longer_defined_falls_through_to_the_config_file_s_implement(tmp_path):
    """The review's case A: the persisted ``gone-implement`` is no longer defined, the file names a valid
    ``cat2-spreader-400``: the service ran with no implement (the guard counted no implement mass) and the line
    said the file's was not taken because the persisted one came first — which was not taken either. The file's
    is taken now, and the line says why the persisted one is not; nothing is written to the store."""
    store = HitchStore(tmp_path / "hitch.sqlite3")
    store.set_setting(SELECTED_SETTING, "gone-implement")
    svc, motion, planning = _restored(store, selected=SPREADER, category="2")
    assert [(r.name, r.mass) for r, _ in motion.selected] == [(SPREADER, 400.0)]
    assert [r.name for r in planning] == [SPREADER] and svc.selected == SPREADER
    assert svc.warnings == [
        f"implement: {SPREADER!r} (the config file's implement) is selected; not taken: 'gone-implement' (the "
        f"persisted selection: {NOT_DEFINED}). {TAIL}"
    ]
    assert store.get_setting(SELECTED_SETTING) == "gone-implement" and store.get_implement(SPREADER) is None


def test_case_a_on_the_simulated_rig_the_guards_count_the_file_s_implement(model, tmp_path):
    path = tmp_path / "hitch.sqlite3"
    store = HitchStore(path)
    store.set_setting(SELECTED_SETTING, "gone-implement")
    store.close()
    svc = SimService(model, path, implement=SPREADER)  # the file's (implement_source "file")
    try:
        assert svc.ok("implements/list")["selected"] == SPREADER and svc.ok("config")["implement"] == SPREADER
        for g in (svc.mc.guard, svc.mc.plan_guard):
            assert g.implement is not None and g.implement.name == SPREADER and g.implement.mass == 400.0
        assert (
            "not taken: 'gone-implement' (the persisted selection: it is not defined" in svc.api.implements.warnings[0]
        )
        assert svc.store.get_setting(SELECTED_SETTING) == "gone-implement"
    finally:
        svc.close()


def test_a_flag_of_another_category_falls_through_to_the_persisted_selection(tmp_path):
    """The review's case B: ``--implement`` names a category-2 implement on a category-3 hitch while a valid stored
    ``plough3`` is persisted: the service ran with no implement. The persisted one is taken now (its record and its
    limits), the line says why the flag's is not, and the persisted selection stays."""
    store = HitchStore(tmp_path / "hitch.sqlite3")
    _plough3(store)
    svc, motion, planning = _restored(store, selected=CAT2, selected_by="flag", category="3")
    assert [(r.name, r.mass, lim.upper_height_m) for r, lim in motion.selected] == [("plough3", 900.0, 0.3)]
    assert [r.name for r in planning] == ["plough3"] and svc.selected == "plough3"
    assert svc.warnings == [
        f"implement: 'plough3' (the persisted selection) is selected; not taken: {CAT2!r} (--implement: {CAT2_ON_3}). "
        f"{TAIL}"
    ]
    assert store.get_setting(SELECTED_SETTING) == "plough3" and store.get_implement(CAT2) is None


def test_case_b_on_a_started_service_the_guards_count_the_persisted_implement(tmp_path):
    """Case B as ``hitch serve --category 3 --implement cat2-power-harrow-1500`` runs it (the control core in the
    service's threads): the guards have ``plough3``, ``config`` names it, the start-up warnings say why the flag's
    implement is not taken."""
    store = HitchStore(tmp_path / "hitch.sqlite3")
    _plough3(store)
    store.close()
    cfg = ServiceConfig(
        listen=[],
        category="3",
        implement=CAT2,
        implement_source="flag",
        control_core="thread",
        planning_processes=0,
        data_dir=tmp_path,
    )
    svc = HitchService(cfg).start()
    try:
        assert svc.motion is not None
        for g in (svc.motion.guard, svc.motion.plan_guard):
            assert g.implement is not None and (g.implement.name, g.implement.mass) == ("plough3", 900.0)
        ok, config = svc.api.handle("config", b"{}")
        assert ok and config["implement"] == "plough3", config
        line = [w for w in svc.warnings if w.startswith("implement: ")]
        assert line == [
            f"implement: 'plough3' (the persisted selection) is selected; not taken: {CAT2!r} (--implement: "
            f"{CAT2_ON_3}). {TAIL}"
        ]
    finally:
        svc.close()


def test_when_every_named_implement_is_invalid_none_runs_and_each_reason_is_said(tmp_path):
    """Every candidate is tried and none can be taken: no implement, and the line gives each one's own reason (not
    "comes before it")."""
    store = HitchStore(tmp_path / "hitch.sqlite3")
    store.set_setting(SELECTED_SETTING, "gone-implement")
    svc, motion, planning = _restored(store, selected=CAT2, category="3")  # the file's, of another category
    assert motion.selected == [] and planning == [] and svc.selected == "default"
    assert svc.warnings == [
        f"implement: no implement is selected; not taken: 'gone-implement' (the persisted selection: {NOT_DEFINED}); "
        f"{CAT2!r} (the config file's implement: {CAT2_ON_3}). {TAIL}"
    ]
    # the flag's of another category, the persisted one not defined
    svc, motion, planning = _restored(store, selected=CAT2, selected_by="flag", category="3")
    assert motion.selected == [] and planning == [] and svc.selected == "default"
    assert svc.warnings == [
        f"implement: no implement is selected; not taken: {CAT2!r} (--implement: {CAT2_ON_3}); 'gone-implement' (the "
        f"persisted selection: {NOT_DEFINED}). {TAIL}"
    ]
    assert store.get_setting(SELECTED_SETTING) == "gone-implement" and store.list_implements() == []


def test_one_left_out_below_the_one_taken_is_said_accurately(tmp_path):
    """The flag's is taken and the persisted one is not defined: a start without the flag would not select it
    either (the line used to say it would). The persisted one is taken and the file's is of another category: the
    line says both reasons."""
    store = HitchStore(tmp_path / "hitch.sqlite3")
    store.set_setting(SELECTED_SETTING, "gone-implement")
    svc, motion, _ = _restored(store, selected=SPREADER, selected_by="flag", category="2")
    assert [r.name for r, _ in motion.selected] == [SPREADER]
    assert svc.warnings == [
        f"implement: {SPREADER!r} (--implement) is selected; not taken: 'gone-implement' (the persisted selection: "
        f"--implement comes first; a start without it would not select it either: {NOT_DEFINED}). {TAIL}"
    ]
    _plough3(store)
    svc, motion, _ = _restored(store, selected=CAT2, category="3")
    assert [r.name for r, _ in motion.selected] == ["plough3"]
    assert svc.warnings == [
        f"implement: 'plough3' (the persisted selection) is selected; not taken: {CAT2!r} (the config file's "
        f"implement: the persisted selection comes before it; nor could it be taken: {CAT2_ON_3}). {TAIL}"
    ]


def test_an_implement_the_controller_refuses_at_start_falls_through_to_the_next(tmp_path):
    """The controller refuses the persisted implement (a HitchError): the file's is tried next, and the line says
    why the persisted one is not taken."""

    class _Refusing(_Motion):
        def select_implement(self, implement: Any, limits: ImplementLimits, *, announce: bool = True) -> dict[str, Any]:
            if implement is not None and implement.name == "plough3":
                raise HitchError("the hitch is above plough3's upper height")
            return super().select_implement(implement, limits, announce=announce)

    store = HitchStore(tmp_path / "hitch.sqlite3")
    _plough3(store)
    store.save_implement(StoredImplement("disc3", "3", 700.0, (0.0, 0.7, 0.3)))
    motion = _Refusing()
    svc = ImplementService(store, motion, selected="disc3", tractor_profile="tractor-6t", category="3")  # type: ignore[arg-type]
    svc.restore()
    assert [r.name for r, _ in motion.selected] == ["disc3"] and svc.selected == "disc3"
    assert svc.warnings == [
        "implement: 'disc3' (the config file's implement) is selected; not taken: 'plough3' (the persisted selection: "
        f"it could not be applied: the hitch is above plough3's upper height). {TAIL}"
    ]


def test_a_profile_record_a_full_store_cannot_take_is_refused_before_the_guards_take_it(tmp_path, monkeypatch):
    """A review: selecting a tractor profile's record with the store full gave the controller's guards the record,
    then the store refused it (``max_implements``): the guards planned with an implement that was not selected.
    The store's room is checked first: nothing changes."""
    import bridge.service.store as store_module

    store = HitchStore(tmp_path / "hitch.sqlite3")
    store.save_implement(StoredImplement("harrow", "2", 1200.0, (0.0, 0.6, 0.4)))
    motion = _Motion()
    svc = ImplementService(store, motion, tractor_profile="tractor-6t", category="2")  # type: ignore[arg-type]
    svc.select("harrow")
    given = list(motion.selected)
    monkeypatch.setattr(store_module, "MAX_IMPLEMENTS", 1)
    with pytest.raises(StoreError, match="limit 1") as err:
        svc.select(CAT2)
    assert err.value.field == "max_implements", err.value
    assert motion.selected == given and svc.selected == "harrow"
    assert store.get_implement(CAT2) is None
    store.close()
