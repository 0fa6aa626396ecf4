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


# ------------------------------------------------------------------------------------------ bounded costs
def _script(i: int, steps: int = 40) -> str:
    body = "".join(f"  - goto: {{z: {0.001 * (k % 100):.3f}}}\n  - wait: 0.{k % 9 + 1}\n" for k in range(steps // 2))
    return f"description: script {i}\ntimeout: 3000\nsteps:\n{body}"


@pytest.fixture
def parse_counter(monkeypatch):
    """Counts every YAML parse of a maneuver script (the store's and the language's)."""
    import bridge.service.maneuvers.language as language
    import bridge.service.store as store_module

    calls = []
    real = language.parse_maneuver

    def counting(text):
        calls.append(text)
        return real(text)

    monkeypatch.setattr(store_module, "parse_maneuver", counting)
    monkeypatch.setattr(language, "parse_maneuver", counting)
    return calls


def test_listing_70_stored_maneuvers_parses_none_of_them(store, parse_counter):
    """One list over 70 stored scripts used to re-parse all 70 (an LRU of 64 thrashed by a scan)."""
    for i in range(70):
        store.save_maneuver(f"m{i:02d}", _script(i))
    assert len(parse_counter) == 70  # each parsed exactly once, at save
    parse_counter.clear()
    for _ in range(3):
        listed = store.list_maneuvers()
        assert [m.name for m in listed] == [f"m{i:02d}" for i in range(70)]
    assert parse_counter == []  # the listing reads stored columns
    first = listed[0].to_json()
    assert first == {"name": "m00", "description": "script 0", "steps": 40, "timeout": 3000.0}
    assert listed[5].size_bytes == len(_script(5).encode())


def test_reading_a_maneuver_back_never_parses_yaml_even_after_reopening(tmp_path, parse_counter):
    path = tmp_path / "h.sqlite3"
    with HitchStore(path) as s:
        saved = {f"m{i}": s.save_maneuver(f"m{i}", _script(i)).parsed for i in range(5)}
    parse_counter.clear()
    with HitchStore(path) as s:  # a new process: nothing cached in memory
        for name, parsed in saved.items():
            got = s.get_maneuver(name)
            assert got is not None and got.parsed == parsed  # rebuilt from the stored form, identical
    assert parse_counter == []


def test_validate_costs_one_parse_however_many_are_stored(model, tmp_path, parse_counter):
    from bridge.service.maneuvers.language import PlanningContext, validate
    from planner.trajectory import MotionState

    with HitchStore(tmp_path / "h.sqlite3") as s:
        for i in range(70):
            s.save_maneuver(f"m{i:02d}", _script(i, steps=4))
        parse_counter.clear()
        ctx = PlanningContext(
            MotionState.at_rest(np.zeros(4)),
            lambda start, goal, scale: (1.0, MotionState.at_rest(np.zeros(4))),
            lambda n: s.get_preset(n),
        )
        assert validate("steps: [{wait: 1}, {goto: {z: 0.1}}]", ctx).ok
    assert len(parse_counter) == 1


def test_a_version_1_database_is_migrated_and_its_maneuvers_parsed_once_at_open(tmp_path, parse_counter):
    from bridge.service.store import MIGRATIONS

    path = tmp_path / "v1.sqlite3"
    db = sqlite3.connect(path)
    db.executescript(MIGRATIONS[0])
    db.execute("INSERT INTO maneuvers VALUES ('old', 'steps: [{wait: 1}, {goto: {z: 0.1}}]', 1.0)")
    db.execute("INSERT INTO maneuvers VALUES ('broken', 'steps: [{wait: 1, wait: 2}]', 2.0)")  # a duplicate key
    db.execute("INSERT INTO presets VALUES ('default', 'slow', 0, 0.1, 0, 0, 0.001, 3.0)")
    db.execute("PRAGMA user_version = 1")
    db.commit()
    db.close()
    with HitchStore(path) as s:
        assert s.schema_version == SCHEMA_VERSION
        assert len(parse_counter) == 2  # at open, once each
        listed = {m.name: m for m in s.list_maneuvers()}
        assert listed["old"].steps == 2 and listed["old"].problem is None
        assert "duplicate key 'wait'" in listed["broken"].to_json()["problem"]
        assert s.get_maneuver("old").parsed.steps[1].z == 0.1
        with pytest.raises(StoreError, match="save it again") as exc:
            s.get_maneuver("broken")
        assert exc.value.field == "script"
        assert s.get_preset("slow").speed_scale == 0.05  # below today's bound: runs at the bound
    parse_counter.clear()
    with HitchStore(path):
        assert parse_counter == []  # migrated once


# ------------------------------------------------------------------------------------------ limits per user
def test_count_and_size_limits_per_user_name_the_limit(tmp_path):
    from bridge.service.store import StoreLimits

    limits = StoreLimits(max_presets_per_user=3, max_maneuvers_per_user=2, max_script_bytes_per_user=200)
    with HitchStore(tmp_path / "h.sqlite3", limits=limits) as s:
        for i in range(3):
            s.save_preset(f"p{i}", POSE, owner="alice", implement=f"imp{i % 2}")
        with pytest.raises(StoreError, match="limit: max_presets_per_user = 3") as exc:
            s.save_preset("p3", POSE, owner="alice")
        assert exc.value.field == "max_presets_per_user" and "'alice'" in str(exc.value)
        s.save_preset("p1", POSE, owner="alice", implement="imp1")  # replacing one of hers does not count twice
        s.save_preset("p3", POSE, owner="bob")  # another user has his own quota
        assert s.get_preset("p3").owner == "bob"
        s.save_maneuver("a", "steps: [{wait: 1}]", owner="alice")
        s.save_maneuver("b", "steps: [{wait: 2}]", owner="alice")
        with pytest.raises(StoreError, match="limit: max_maneuvers_per_user = 2") as exc:
            s.save_maneuver("c", "steps: [{wait: 3}]", owner="alice")
        assert exc.value.field == "max_maneuvers_per_user"
        s.save_maneuver("b", "steps: [{wait: 4}]", owner="alice")  # a replacement fits
        with pytest.raises(StoreError, match="limit: max_script_bytes_per_user = 200 bytes") as exc:
            s.save_maneuver("big", "description: " + "x" * 190 + "\nsteps: [{wait: 1}]", owner="carol")
        assert exc.value.field == "max_script_bytes_per_user"
        with pytest.raises(StoreError, match="anonymous"):
            for i in range(4):
                s.save_preset(f"anon{i}", POSE)  # no user named (Zenoh): one shared quota
        assert [m.name for m in s.list_maneuvers()] == ["a", "b"]
        assert s.get_maneuver("b").parsed.steps[0].seconds == 4.0
    with pytest.raises(StoreError, match="max_presets_per_user"):
        StoreLimits(max_presets_per_user=0)


# ------------------------------------------------------------------------------------------ integrity
def test_a_database_with_damaged_pages_is_refused_at_open_naming_the_file(tmp_path):
    path = tmp_path / "damaged.sqlite3"
    with HitchStore(path) as s:
        for i in range(300):
            s.save_preset(f"preset-{i:04d}-{'x' * 40}", POSE)
    data = bytearray(path.read_bytes())
    pages = len(data) // 4096
    assert pages > 8
    page = pages // 2
    data[page * 4096 : (page + 1) * 4096] = b"\xa5" * 4096  # one b-tree page overwritten
    path.write_bytes(bytes(data))
    db = sqlite3.connect(path)  # the header is intact: opening and reading the schema version still work
    assert db.execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION
    db.close()
    with pytest.raises(StoreError) as exc:
        HitchStore(path)
    assert exc.value.field == "path" and str(path) in str(exc.value) and "damaged" in str(exc.value)
    assert "quick_check" in str(exc.value)
