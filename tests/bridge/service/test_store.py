"""SQLite store: round trips, per-implement uniqueness, field-naming errors, schema versions,
concurrency, clean close, and durability of acknowledged presets under kill -9."""

import math
import os
import signal
import sqlite3
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from bridge.service.maneuvers.language import ManeuverError
from bridge.service.store import DEFAULT_IMPLEMENT, SCHEMA_VERSION, HitchStore, StoreError

POSE = {"x": 0.01, "z": 0.12, "roll": -0.02, "pitch": 0.03}


@pytest.fixture
def store(tmp_path):
    s = HitchStore(tmp_path / "data" / "hitch.sqlite3")
    yield s
    s.close()


def test_preset_round_trip_is_exact_and_replaces_atomically(store, rng):
    poses = {f"p{i}": dict(zip(POSE, rng.uniform(-0.3, 0.3, 4), strict=True)) for i in range(20)}
    for name, pose in poses.items():
        store.save_preset(name, pose, implement="cat2-spreader", speed_scale=0.5)
    got = {p.name: p for p in store.list_presets("cat2-spreader")}
    assert sorted(got) == sorted(poses)
    for name, pose in poses.items():
        assert dict(got[name].pose) == pose  # REAL columns keep the float64 bits
        assert got[name].speed_scale == 0.5 and got[name].implement == "cat2-spreader"
    # saving the same name again replaces it (insert or replace), no duplicate row
    new = {"x": 0.0, "z": -0.1, "roll": 0.0, "pitch": 0.0}
    store.save_preset("p3", new, implement="cat2-spreader")
    assert len(store.list_presets("cat2-spreader")) == 20
    p3 = store.get_preset("p3", implement="cat2-spreader")
    assert dict(p3.pose) == new and p3.speed_scale is None
    assert store.get_preset("nope", implement="cat2-spreader") is None


def test_names_are_unique_per_implement(store):
    store.save_preset("transport", POSE, implement="plough")
    store.save_preset("transport", {**POSE, "z": 0.3}, implement="harrow")
    store.save_preset("work", POSE)
    assert store.get_preset("transport", implement="plough").pose["z"] == POSE["z"]
    assert store.get_preset("transport", implement="harrow").pose["z"] == 0.3
    assert [p.name for p in store.list_presets()] == ["work"]  # the default implement's only
    assert store.list_presets()[0].implement == DEFAULT_IMPLEMENT
    assert [(p.implement, p.name) for p in store.list_presets(None)] == [
        ("default", "work"),
        ("harrow", "transport"),
        ("plough", "transport"),
    ]
    assert store.delete_preset("transport", implement="plough") is True
    assert store.delete_preset("transport", implement="plough") is False
    assert store.get_preset("transport", implement="harrow") is not None
    assert store.list_presets("plough") == []


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"name": "has space"}, "name"),
        ({"name": ""}, "name"),
        ({"name": "x" * 65}, "name"),
        ({"name": 7}, "name"),
        ({"implement": "../etc"}, "implement"),
        ({"pose": {"x": 0.0, "z": 0.0, "roll": 0.0}}, "pose.pitch"),
        ({"pose": {**POSE, "yaw": 0.0}}, "pose"),
        ({"pose": {**POSE, "z": math.nan}}, "pose.z"),
        ({"pose": {**POSE, "x": math.inf}}, "pose.x"),
        ({"pose": {**POSE, "roll": 2.0}}, "pose.roll"),
        ({"pose": {**POSE, "x": "0.1"}}, "pose.x"),
        ({"pose": {**POSE, "x": True}}, "pose.x"),
        ({"pose": [0, 0, 0, 0]}, "pose"),
        ({"speed_scale": 0.0}, "speed_scale"),
        ({"speed_scale": 1.5}, "speed_scale"),
        ({"speed_scale": math.nan}, "speed_scale"),
    ],
)
def test_bad_preset_values_name_the_field_and_store_nothing(store, kwargs, field):
    args = {"name": "ok", "pose": POSE, **kwargs}
    with pytest.raises(StoreError) as exc:
        store.save_preset(args.pop("name"), args.pop("pose"), **args)
    assert exc.value.field == field
    assert str(exc.value).startswith(field)
    assert isinstance(exc.value, ValueError)
    assert store.list_presets(None) == []


def test_maneuvers_are_parsed_before_storing_and_cached(store):
    script = "description: lift\nsteps:\n  - goto: {z: 0.2}\n  - wait: 1.0\n"
    m = store.save_maneuver("lift", script)
    assert m.parsed.steps[0].z == 0.2 and m.parsed.description == "lift"
    got = store.get_maneuver("lift")
    assert got.script == script
    assert got.parsed is store.get_maneuver("lift").parsed  # the parsed form is cached, not re-parsed
    store.save_maneuver("lift", "steps: [{wait: 2}]")  # replace
    assert store.get_maneuver("lift").parsed.steps[0].seconds == 2.0
    assert [m.name for m in store.list_maneuvers()] == ["lift"]
    assert store.list_maneuvers()[0].to_json()["steps"] == 1
    with pytest.raises(ManeuverError) as exc:
        store.save_maneuver("bad", "steps:\n  - wait: 1\n  - goto: {z: 9}\n")
    assert exc.value.errors[0].step == 1 and "z" in exc.value.errors[0].message
    with pytest.raises(StoreError) as exc:
        store.save_maneuver("a", "name: b\nsteps: [{wait: 1}]")
    assert exc.value.field == "name"
    with pytest.raises(StoreError) as exc:
        store.save_maneuver("a", b"steps: []")
    assert exc.value.field == "script"
    assert store.get_maneuver("bad") is None and store.get_maneuver("a") is None
    assert store.delete_maneuver("lift") is True and store.delete_maneuver("lift") is False
    assert store.list_maneuvers() == []


def test_wal_full_sync_and_schema_version(store, tmp_path):
    assert store.pragmas() == {"journal_mode": "wal", "synchronous": 2}  # 2 = FULL
    assert store.schema_version == SCHEMA_VERSION
    other = sqlite3.connect(store.path)  # an independent reader sees the same schema and mode
    assert other.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert other.execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION
    other.close()


def test_a_newer_schema_or_a_foreign_file_is_refused(tmp_path):
    newer = tmp_path / "newer.sqlite3"
    db = sqlite3.connect(newer)
    db.execute(f"PRAGMA user_version = {SCHEMA_VERSION + 5}")
    db.close()
    with pytest.raises(StoreError) as exc:
        HitchStore(newer)
    assert exc.value.field == "schema_version" and str(SCHEMA_VERSION + 5) in str(exc.value)
    junk = tmp_path / "junk.sqlite3"
    junk.write_bytes(b"this is not a database" * 100)
    with pytest.raises(StoreError) as exc:
        HitchStore(junk)
    assert exc.value.field == "path"


def test_reopening_keeps_data_and_migrations_run_once(tmp_path):
    path = tmp_path / "h.sqlite3"
    with HitchStore(path) as s:
        s.save_preset("a", POSE)
    with HitchStore(path) as s:
        assert s.schema_version == SCHEMA_VERSION
        assert [p.name for p in s.list_presets()] == ["a"]


def test_close_checkpoints_and_later_calls_fail_cleanly(tmp_path):
    path = tmp_path / "h.sqlite3"
    s = HitchStore(path)
    s.save_preset("a", POSE)
    s.close()
    s.close()  # idempotent
    wal = Path(str(path) + "-wal")
    assert not wal.exists() or wal.stat().st_size == 0  # checkpointed into the main file
    with pytest.raises(StoreError) as exc:
        s.get_preset("a")
    assert exc.value.field == "store"


def test_concurrent_writers_and_readers(store):
    errors = []

    def writer(k):
        try:
            for i in range(40):
                store.save_preset(f"t{k}-{i}", {**POSE, "x": k / 100, "z": i / 1000}, implement=f"imp{k}")
        except Exception as exc:  # collected for the assertion below
            errors.append(exc)

    def reader():
        try:
            for _ in range(60):
                for p in store.list_presets(None):
                    assert p.pose["x"] == int(p.implement[3:]) / 100
        except Exception as exc:
            errors.append(exc)

    threads = [threading.Thread(target=writer, args=(k,)) for k in range(6)] + [
        threading.Thread(target=reader) for _ in range(3)
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=30)
    assert not errors
    assert len(store.list_presets(None)) == 6 * 40
    assert store.get_preset("t5-39", implement="imp5").pose["z"] == 0.039


_WRITER = """
import sys
from bridge.service.store import HitchStore
s = HitchStore({path!r})
i = int(sys.argv[1])
while True:
    s.save_preset(f"p{{i}}", {{"x": i * 1e-6, "z": 0.1, "roll": 0.0, "pitch": -i * 1e-7}}, implement="dur")
    print(f"p{{i}}", flush=True)
    i += 1
"""


@pytest.mark.slow  # a writer process killed with SIGKILL
def test_kill_9_during_preset_writes_loses_no_acknowledged_preset(tmp_path):
    path = tmp_path / "durable.sqlite3"
    script = tmp_path / "writer.py"
    script.write_text(_WRITER.format(path=str(path)))
    rng = np.random.default_rng(7)
    acknowledged: list[str] = []
    start = 0
    for round_ in range(3):
        stop_after = int(rng.integers(40, 160))
        proc = subprocess.Popen([sys.executable, str(script), str(start)], stdout=subprocess.PIPE, text=True)
        try:
            got = 0
            for line in proc.stdout:
                acknowledged.append(line.strip())
                got += 1
                if got >= stop_after:
                    break
            os.kill(proc.pid, signal.SIGKILL)  # mid-stream: the writer is inside its next save
        finally:
            proc.kill()
            proc.wait(timeout=10)
            proc.stdout.close()
        assert proc.returncode == -signal.SIGKILL
        assert got == stop_after, f"round {round_}: the writer stopped early"
        start += 100_000
    with HitchStore(path) as s:
        present = {p.name: p for p in s.list_presets("dur")}
    missing = [n for n in acknowledged if n not in present]
    assert not missing, f"{len(missing)} acknowledged presets lost, e.g. {missing[:5]}"
    for n in acknowledged:
        i = int(n[1:])
        assert present[n].pose["x"] == i * 1e-6 and present[n].pose["pitch"] == -i * 1e-7
