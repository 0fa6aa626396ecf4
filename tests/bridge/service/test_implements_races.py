"""Implements under concurrent requests (bridge.service.implements): a transport lock set while an
implement is being redefined is kept (define read the stored lock outside the service's lock and wrote
the stale "unlocked" back: the hitch could move while the operator had locked it); and the store's
migrations reach the current schema from every earlier version."""

from __future__ import annotations

import sqlite3
import threading

import pytest

from bridge.service.store import MIGRATIONS, SCHEMA_VERSION, HitchStore
from tests.helpers import SimService

HARROW = {"name": "harrow", "category": "2", "mass_kg": 1200.0, "com_m": [0.0, 0.6, 0.4]}


def test_a_lock_set_while_the_selected_implement_is_redefined_is_kept(model, tmp_path):
    svc = SimService(model, tmp_path / "hitch.sqlite3")
    try:
        assert svc.call("implements/define", HARROW)[0]
        assert svc.call("implements/select", {"name": "harrow"})[0]
        store = svc.api.implements.store
        real_get = store.get_implement
        fired: list[threading.Thread] = []

        def get_implement(name: str):  # right after define's first read, an operator locks
            found = real_get(name)
            if not fired:
                t = threading.Thread(target=lambda: svc.call("implements/lock"))
                fired.append(t)
                t.start()
                t.join(timeout=1.0)  # done at once when define holds no lock; else it waits for define
            return found

        store.get_implement = get_implement  # type: ignore[method-assign]
        ok, r = svc.call("implements/define", {**HARROW, "mass_kg": 1300.0})
        assert ok, r
        fired[0].join(timeout=10.0)
        assert not fired[0].is_alive()
        store.get_implement = real_get  # type: ignore[method-assign]
        assert real_get("harrow").limits.transport_locked is True
        assert svc.mc.guard.implement_limits.transport_locked is True
        ok, r = svc.call("goto", {"goal": {"z": 0.2}})
        assert not ok and r["error"] == "locked", r
    finally:
        svc.close()


@pytest.mark.parametrize("version", [2, 3, 4])
def test_a_database_of_an_earlier_schema_version_reaches_the_current_one(tmp_path, version):
    path = tmp_path / "old.sqlite3"
    db = sqlite3.connect(path)
    for statement in ";".join(MIGRATIONS[:version]).split(";"):
        if statement.strip():
            db.execute(statement)
    db.execute(f"PRAGMA user_version = {version}")
    db.commit()
    db.close()
    store = HitchStore(path)
    try:
        assert store.schema_version == SCHEMA_VERSION
        store.save_line("north", [[8.0, 47.0], [8.001, 47.0]])
        store.save_work_settings("harrow", {"mode": "draft"})
        store.set_setting("selected_implement", "harrow")
        assert store.list_lines() == [("north", [[8.0, 47.0], [8.001, 47.0]])]
        assert store.get_work_settings("harrow") == {"mode": "draft"}
    finally:
        store.close()


RAKE = {
    "name": "rake",
    "category": "2",
    "mass_kg": 100.0,
    "com_m": [0.0, 0.3, 0.2],
    "headland": {"x": 0.0, "z": 0.12, "roll": 0.0, "pitch": 0.0},
}


def _listed_when_announced(svc: SimService, key: str, payload: dict) -> dict:
    """What ``implements/list`` (``presets/list`` under "presets") answers when sent the moment the
    ``implement_selected`` event of ``key`` is delivered (the terminal refreshes its chooser and presets on that
    event; CI: the event came before the selection was recorded, the chooser kept "no implement" and Raise stayed
    disabled)."""
    listed: list[dict] = []
    fired: list[threading.Thread] = []

    def on_event(event: dict) -> None:
        if event.get("event") != "implement_selected":
            return

        def ask() -> None:  # as the terminal does: its chooser and the implement's presets
            listed.append({**svc.call("implements/list")[1], "presets": svc.call("presets/list")[1]})

        t = threading.Thread(target=ask)
        fired.append(t)
        t.start()
        t.join(timeout=0.5)  # answered at once if nothing holds it back (the old order: before the change)

    svc.event_listeners.append(on_event)
    try:
        ok, r = svc.call(key, payload)
        assert ok, r
    finally:
        svc.event_listeners.remove(on_event)
    assert len(fired) == 1
    fired[0].join(timeout=10.0)
    assert not fired[0].is_alive()
    return listed[0]


def test_a_list_asked_on_the_selection_event_names_the_new_selection(model, tmp_path):
    svc = SimService(model, tmp_path / "hitch.sqlite3")
    try:
        assert svc.call("implements/define", RAKE)[0]
        listed = _listed_when_announced(svc, "implements/select", {"name": "rake"})
        assert listed["selected"] == "rake", listed
        assert listed["presets"]["implement"] == "rake", listed  # the presets are the implement's
    finally:
        svc.close()


@pytest.mark.parametrize(
    ("first", "key", "payload", "field", "shown"),
    [
        ({**RAKE, "headland": None}, "implements/define", RAKE, "headland", RAKE["headland"]),  # redefined
        (RAKE, "implements/lock", {}, "transport_locked", True),
    ],
    ids=["redefined", "locked"],
)
def test_a_list_asked_on_the_change_event_shows_the_changed_record(model, tmp_path, first, key, payload, field, shown):
    svc = SimService(model, tmp_path / "hitch.sqlite3")
    try:
        assert svc.call("implements/define", first)[0]
        assert svc.call("implements/select", {"name": "rake"})[0]
        listed = _listed_when_announced(svc, key, payload)
        (rake,) = [i for i in listed["implements"] if i["name"] == "rake"]
        assert rake[field] == shown, rake
    finally:
        svc.close()
