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
