"""The black box (bridge.service.blackbox): event log, CAN recorder and replay.

Truth: the records we put in (read back line by line as JSON), the size limit and file count we
set for rotation, the frames we send (compared with python-can's own readers), and for the replay
the AD calibration + forward kinematics of the counts we encoded (computed here independently
of the link).
"""

from __future__ import annotations

import json
import threading
import time

import can
import numpy as np
import pytest

from bridge.isobus.codec import load_codec
from bridge.isobus.messages import Heartbeat, PositionCounts, PositionMeasurement, RearHitchStatus
from bridge.service.blackbox import (
    BlackBoxError,
    CanRecorder,
    EventLog,
    announce_can_log_stop,
    event_log_path,
    follow_events,
    last_seq,
    read_events,
    replay_can_log,
)
from bridge.service.config import ServiceConfig
from bridge.service.motion.outbox import Outbox
from bridge.service.server import HitchService
from planner.model.kinematics import HitchModel
from planner.model.sensors import SensorScaling
from tests.helpers import wait_until


# ---------------------------------------------------------------------------------------- event log
def test_records_are_json_lines_in_order_with_who_what_and_outcome(tmp_path):
    path = event_log_path(tmp_path)
    assert path == tmp_path / "log" / "events.jsonl"
    log = EventLog(path)
    log.on_request("goto", "alice", b'{"goal": {"z": 0.2}}', True, {"motion_id": 7, "duration": 1.0})
    log.on_request("presets/save", "bob", b'{"name": "w"}', False, {"error": "forbidden", "message": "viewer"})
    log.on_request("config", None, b"", True, {"profile": "p"})  # not recorded: every client asks it once
    log.on_request("ik", None, b"", True, {"status": "ok"})
    log.on_event({"t": 12.5, "event": "fault", "fault": "stale_measurement", "message": "no 0xFF22"})
    log.on_event({"t": 13.0, "event": "motion_finished", "motion_id": 7, "seq": 41})
    log.close()
    lines = path.read_text(encoding="utf-8").splitlines()
    recs = [json.loads(x) for x in lines]
    assert [r["seq"] for r in recs] == [1, 2, 3, 4, 5]
    assert recs[0] == {**recs[0], "kind": "request", "key": "goto", "user": "alice", "accepted": True, "motion_id": 7}
    assert json.loads(recs[0]["request"]) == {"goal": {"z": 0.2}}
    assert recs[1]["accepted"] is False and recs[1]["error"] == "forbidden" and recs[1]["user"] == "bob"
    assert recs[2]["key"] == "ik" and "request" not in recs[2]  # a reading request's body is not kept
    assert recs[3]["kind"] == "event" and recs[3]["fault"] == "stale_measurement" and recs[3]["event_t"] == 12.5
    assert recs[4]["event"] == "motion_finished" and recs[4]["event_seq"] == 41 and recs[4]["seq"] == 5
    assert read_events(path) == recs


def test_an_event_keeps_its_motion_kind_so_a_stop_reads_apart_from_a_goto(tmp_path):
    """A new user's report: the black box dropped the event's ``kind``, so its records could not tell a stop
    from a goto, preset or jog. ``kind`` names the record, so the event's own is kept as ``event_kind``."""
    path = event_log_path(tmp_path)
    log = EventLog(path)
    for mid, kind in enumerate(("goto", "preset", "jog", "stop"), start=1):
        log.on_event({"t": 1.0, "event": "motion_started", "motion_id": mid, "kind": kind, "seq": mid})
    log.on_event({"t": 2.0, "event": "motion_finished", "motion_id": 4, "kind": "stop", "seq": 5})
    log.close()
    recs = read_events(path)
    assert all(r["kind"] == "event" for r in recs)
    assert [(r["motion_id"], r.get("event_kind")) for r in recs] == [
        (1, "goto"),
        (2, "preset"),
        (3, "jog"),
        (4, "stop"),
        (4, "stop"),
    ]


def test_record_numbers_go_on_across_service_starts_so_a_number_names_one_record(tmp_path):
    """Before, each service start numbered its records from 1 again in the same file (a new user's
    report: ``hitch log`` showed two records #1). A torn last line (killed writer) is skipped; after a
    rotation the newest rotated file gives the number; an empty folder starts at 1."""
    path = event_log_path(tmp_path)
    assert last_seq(path) == 0
    for run in range(3):
        with EventLog(path) as log:
            log.record("service", run=run)
            log.record("test", run=run)
    assert [r["seq"] for r in read_events(path)] == [1, 2, 3, 4, 5, 6]
    with path.open("a", encoding="utf-8") as fh:
        fh.write('{"seq":7,"t":1.0,"kind":"te')  # a writer killed mid-line
    assert last_seq(path) == 6
    path.write_text("")  # just rotated: the live file is empty
    (path.parent / "events.jsonl.1").write_text('{"seq":41,"t":1.0,"kind":"test"}\n')
    with EventLog(path) as log:
        log.record("test")
    assert read_events(path)[-1]["seq"] == 42
    log = EventLog(path, max_bytes=2000, backup_count=2)  # numbers stay increasing through rotations
    for i in range(100):
        log.record("test", i=i, pad="x" * 40)
    log.close()
    seqs = [r["seq"] for r in read_events(path) if r.get("kind") == "test"]
    assert seqs == sorted(seqs) and seqs[-1] == 142


def test_the_log_rotates_by_size_and_keeps_a_bounded_number_of_files(tmp_path):
    path = event_log_path(tmp_path)
    log = EventLog(path, max_bytes=2000, backup_count=3)
    for i in range(400):
        assert log.record("test", i=i, pad="x" * 40)
    log.close()
    files = sorted(p.name for p in path.parent.iterdir())
    assert files == ["events.jsonl", "events.jsonl.1", "events.jsonl.2", "events.jsonl.3"]
    for p in path.parent.iterdir():
        assert p.stat().st_size <= 2000
    recs = read_events(path)
    seqs = [r["seq"] for r in recs]
    assert seqs == sorted(seqs) and seqs[-1] == 400  # oldest first, the newest kept
    assert len(recs) < 400  # the oldest were dropped with the oldest file
    assert [r["i"] for r in recs] == [s - 1 for s in seqs]


def test_log_files_are_readable_by_the_service_s_user_only_also_after_a_rotation(tmp_path):
    """A fleet trial: the black box files were 0644 where the data folder existed already; they name users and
    carry their requests."""
    import os
    import stat

    old = os.umask(0o022)  # the usual umask: what files get without a mode of their own
    try:
        path = event_log_path(tmp_path)
        log = EventLog(path, max_bytes=2000, backup_count=2)
        for i in range(200):
            log.record("test", i=i, pad="x" * 40)
        log.close()
    finally:
        os.umask(old)
    files = list(path.parent.iterdir())
    assert len(files) == 3
    for p in files:
        assert stat.S_IMODE(p.stat().st_mode) == 0o600, (p.name, oct(p.stat().st_mode))


def test_record_never_blocks_and_counts_what_it_drops(tmp_path):
    log = EventLog(event_log_path(tmp_path), queue_size=5)
    gate = threading.Event()
    real = log._write

    def slow_write(rec):
        gate.wait(5.0)
        real(rec)

    log._write = slow_write  # the writer is stuck on the disk
    t0 = time.monotonic()
    results = [log.record("test", i=i) for i in range(50)]
    assert time.monotonic() - t0 < 1.0  # the caller (the control thread) was never held up
    assert results.count(False) == log.dropped > 0
    gate.set()
    log.close()
    recs = read_events(event_log_path(tmp_path))
    dropped = [r for r in recs if r["kind"] == "dropped"]
    assert sum(r["count"] for r in dropped) == log.dropped
    assert [r["i"] for r in recs if r["kind"] == "test"] == [i for i, ok in enumerate(results) if ok]


def test_non_json_values_are_rendered_and_bad_settings_refused(tmp_path):
    log = EventLog(event_log_path(tmp_path))
    log.record("test", value=float("nan"), arr=np.float64(0.5), t2=(1, 2))
    log.close()
    (rec,) = read_events(event_log_path(tmp_path))
    assert rec["value"] == "nan" and rec["arr"] == 0.5 and rec["t2"] == [1, 2]
    for kw, needle in (({"max_bytes": 0}, "max_bytes"), ({"backup_count": 0}, "backup_count")):
        with pytest.raises(BlackBoxError, match=needle):
            EventLog(event_log_path(tmp_path), **kw)


def test_follow_yields_new_records_across_a_rotation(tmp_path):
    path = event_log_path(tmp_path)
    log = EventLog(path, max_bytes=600, backup_count=2)
    log.record("old")
    assert log.flush()
    got: list[dict] = []
    end = time.monotonic() + 10.0

    def reader() -> None:
        for rec in follow_events(path, poll_s=0.02, should_stop=lambda: len(got) >= 20 or time.monotonic() > end):
            got.append(rec)

    th = threading.Thread(target=reader)
    th.start()
    time.sleep(0.2)
    for i in range(20):
        log.record("new", i=i, pad="y" * 40)
        time.sleep(0.01)
    log.close()
    th.join(12.0)
    assert [r["i"] for r in got] == list(range(20))  # nothing lost or repeated; the old record not re-read
    assert (path.parent / "events.jsonl.1").exists()  # it did rotate meanwhile


def test_a_log_that_appeared_after_the_caller_found_none_is_followed_from_its_start(tmp_path):
    """`hitch log --follow` found no log, said it waits, and the service wrote its first records before the
    follower opened the file: they were skipped (the follower read a log that exists from its end; CI run 33)."""
    path = event_log_path(tmp_path)
    assert not path.exists()  # what the caller saw
    log = EventLog(path)
    log.record("first")
    assert log.flush()
    got: list[str] = []
    end = time.monotonic() + 5.0
    try:
        for rec in follow_events(path, poll_s=0.01, from_start=True, should_stop=lambda: time.monotonic() > end):
            got.append(rec["kind"])
            break
    finally:
        log.close()
    assert got == ["first"], got
    # without from_start an existing log is read from its end (what a caller that printed it wants)
    log = EventLog(path)
    log.record("second")
    log.close()
    end = time.monotonic() + 0.3
    later = list(follow_events(path, poll_s=0.01, should_stop=lambda: time.monotonic() > end))
    assert later == []


def test_the_api_hook_sees_every_request_and_its_failure_cannot_fail_the_request():
    from bridge.service.api import ServiceAPI

    class Motion:  # what the `config` request reads; a goto with a bad body never reaches the motion
        mode = "auto"

    api = ServiceAPI(Motion(), None, None, {"profile": "p"})  # type: ignore[arg-type]
    seen: list[tuple] = []
    api.on_request = lambda *a: seen.append(a)
    ok, reply = api.handle("config", b"{}", "alice")
    assert ok and seen[-1][:2] == ("config", "alice") and seen[-1][3] is True
    ok, reply = api.handle("goto", b"{not json", None)
    assert not ok and seen[-1][0] == "goto" and seen[-1][3] is False and seen[-1][4] == reply

    def broken(*a):
        raise RuntimeError("recorder bug")

    api.on_request = broken
    assert api.handle("config", b"{}", None)[0]


# ---------------------------------------------------------------------------------------- CAN
def _frames() -> list[can.Message]:
    codec = load_codec()
    return [
        codec.encode(Heartbeat(7), source=169),
        codec.encode(PositionCounts(300, 400, 500, 600, 700), source=166),
        codec.encode(PositionMeasurement(401, 502, 703, 604, 0), source=169),
        can.Message(arbitration_id=0x18FEEEAB, is_extended_id=True, data=bytes(range(8))),
    ]


@pytest.mark.parametrize("suffix", [".asc", ".log", ".blf"])
def test_recorder_round_trip_through_python_can_readers(tmp_path, suffix):
    channel = f"bb-rec-{suffix[1:]}"
    path = tmp_path / f"bus{suffix}"
    rec = CanRecorder(path, "virtual", channel)
    sender = can.Bus(interface="virtual", channel=channel)
    try:
        sent = _frames()
        for f in sent:
            sender.send(f)
            time.sleep(0.01)
        time.sleep(0.3)  # the notifier thread writes them
    finally:
        rec.close()
        sender.shutdown()
    back = [m for m in can.LogReader(str(path)) if not m.is_error_frame]
    assert [(m.arbitration_id, bytes(m.data), m.is_extended_id) for m in back] == [
        (m.arbitration_id, bytes(m.data), True) for m in sent
    ]


def test_recorder_refuses_an_unknown_suffix(tmp_path):
    with pytest.raises(BlackBoxError, match="--can-log"):
        CanRecorder(tmp_path / "bus.unknownformat", "virtual", "bb-bad")


def test_replay_decodes_known_frames_into_the_measured_pose_and_raises_a_stale_fault(tmp_path):
    model = HitchModel.from_profile("thesis-t132")
    scale = SensorScaling(model.profile)
    counts = np.rint(scale.counts_min + (model.neutral - scale.si_min) / scale.resolution).astype(int)
    counts[1] += 12  # tilt off neutral: a non-trivial roll
    lift_min, lift_max = float(scale.counts_min[0]), float(scale.counts_max[0])
    fraction = (counts[0] - lift_min) / (lift_max - lift_min)
    codec = load_codec()
    meas = PositionMeasurement(int(counts[1]), int(counts[2]), int(counts[4]), int(counts[3]), 0)
    frames: list[can.Message] = []
    t = 1000.0
    for k in range(20):  # 200 ms of a healthy ECU: 100 Hz measurement, hitch status and heartbeat at 10 Hz
        tk = t + 0.01 * k
        frames.append(codec.encode(meas, source=169))
        frames[-1].timestamp = tk
        if k % 10 == 0:
            for p in (RearHitchStatus(position=fraction), Heartbeat(k // 10)):
                frames.append(codec.encode(p, source=169))
                frames[-1].timestamp = tk
    ref = codec.encode(PositionCounts(*map(int, counts)), source=166)
    ref.timestamp = t + 0.2
    frames.append(ref)
    late = codec.encode(meas, source=169)  # after a 600 ms silence: the link must call it stale
    late.timestamp = t + 0.8
    frames.append(late)
    path = tmp_path / "bus.log"
    with can.CanutilsLogWriter(str(path), channel="vcan0") as w:
        for f in frames:
            w.on_message_received(f)
    everything = list(replay_can_log(path, model))
    fault_recs = [r for r in everything if r.name == "fault"]
    recs = [r for r in everything if r.name != "fault"]
    assert len(recs) == len(frames)
    assert recs[0].t_s == 0.0 and recs[-1].t_s == pytest.approx(0.8, abs=1e-6)
    expected = model.forward(scale.to_si(counts)).pose  # AD calibration + FK of what we encoded
    poses = [r.pose for r in recs if r.pose is not None]
    assert poses, "no measured pose came out of the replay"
    for got in poses:
        for k in ("x", "z", "roll", "pitch"):
            assert got[k] == pytest.approx(getattr(expected, k), abs=1e-9)
    refs = [r for r in recs if r.name == "PositionCounts"]
    assert len(refs) == 1 and refs[0].source == 166 and refs[0].fields["tilt"] == counts[1]
    assert [r.name for r in recs[:3]] == ["PositionMeasurement", "RearHitchStatus", "Heartbeat"]
    # the last hitch status (the lift) came at 0.1 s: the 0.2 s stale limit passes at 0.3 s, in the silence
    assert fault_recs, "the 600 ms silence raised no fault"
    first = fault_recs[0]
    assert first.t_s == pytest.approx(0.3, abs=0.025)
    assert any("stale" in f or "no valid" in f for f in first.faults) and "lift" in first.faults[0]
    assert json.dumps([r.to_json() for r in everything])  # JSON-able for `hitch replay --json`


def test_replay_of_a_missing_or_unknown_file_is_a_clear_error(tmp_path):
    model = HitchModel.from_profile("thesis-t132")
    with pytest.raises(BlackBoxError, match="does not exist"):
        list(replay_can_log(tmp_path / "nope.asc", model))
    with pytest.raises(BlackBoxError, match=r"is a folder: give one of its log files"):  # it said "does not exist"
        list(replay_can_log(tmp_path, model))
    bad = tmp_path / "bus.weird"
    bad.write_text("x", encoding="utf-8")
    with pytest.raises(BlackBoxError, match="cannot read"):
        list(replay_can_log(bad, model))


@pytest.mark.parametrize(
    ("name", "content", "expect"),
    [
        ("bad.log", b"(1.000000) vcan0 18FF22A9#GGGG\n", r"bad\.log: cannot read frame 1 \(ValueError: .*'GG'"),
        ("random.log", bytes(range(128, 256)) * 8, r"cannot read frame 1 \(UnicodeDecodeError"),
        ("random.blf", bytes(range(256)) * 4, r"random\.blf: cannot read \(BLFParseError"),
        ("empty.blf", b"", r"empty\.blf: cannot read \(error: unpack"),
        (
            "backwards.log",
            b"(1.000000) vcan0 18FF22A9#0000000000000000\n(0.500000) vcan0 18FF22A9#0000000000000000\n",
            r"frame 2 at 0\.500000 s goes back in time from 1\.000000 s",
        ),
    ],
)
def test_replay_of_a_damaged_log_names_the_file_and_the_frame(tmp_path, name, content, expect):
    """An attacker's report: each of these was a Python traceback out of python-can's readers (ValueError,
    UnicodeDecodeError, BLFParseError, struct.error), and a log going back in time was replayed without a word."""
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(BlackBoxError, match=expect):
        list(replay_can_log(path, HitchModel.from_profile("thesis-t132")))


def _numbered(k: int) -> can.Message:
    return can.Message(arbitration_id=0x18FEEEAB, is_extended_id=True, data=k.to_bytes(4, "big") + b"\0\0\0\0")


def _numbers(path) -> list[int]:
    return [int.from_bytes(bytes(m.data[:4]), "big") for m in can.LogReader(str(path)) if not m.is_error_frame]


@pytest.mark.parametrize("suffix", [".asc", ".log", ".blf"])
def test_the_can_log_rotates_by_size_keeps_its_last_files_and_loses_no_frame_in_them(tmp_path, suffix):
    """About five files' worth of frames through a recorder of 100 kB files keeping 2 rotated ones: the
    newest file and two rotated ones remain, each readable by python-can and within the size (plus one
    frame), and together they hold the newest frames without a gap, in order. Before, the log grew
    without bound (8 MB in about 5 minutes of a service at rest)."""
    channel = f"bb-rot-{suffix[1:]}-{time.monotonic_ns()}-x"
    path = tmp_path / f"bus{suffix}"
    rec = CanRecorder(path, "virtual", channel, max_bytes=100_000, keep=2)
    sender = can.Bus(interface="virtual", channel=channel)
    per_file = 2000 if suffix != ".blf" else 8000  # rough frames per 100 kB (BLF's size counts uncompressed data)
    n = 5 * per_file
    try:
        for k in range(n):
            sender.send(_numbered(k))
            if k % 500 == 499:
                time.sleep(0.02)
        deadline = time.monotonic() + 20.0
        while time.monotonic() < deadline and rec.frames_written < n:
            time.sleep(0.05)
    finally:
        rec.close()
        sender.shutdown()
    assert rec.frames_written == n
    files = sorted(p.name for p in tmp_path.iterdir())
    assert files == sorted([f"bus{suffix}", f"bus.1{suffix}", f"bus.2{suffix}"]), files
    kept = [_numbers(tmp_path / f"bus.2{suffix}"), _numbers(tmp_path / f"bus.1{suffix}"), _numbers(path)]
    assert all(kept), [len(k) for k in kept]
    seq = [k for part in kept for k in part]
    assert seq == list(range(seq[0], n)), "a gap or a reordering across the rotated files"
    assert seq[0] > 0  # the oldest files were deleted
    for name in (f"bus.2{suffix}", f"bus.1{suffix}"):
        assert (tmp_path / name).stat().st_size <= 100_000 + 70_000  # one frame (or one BLF container) over


def test_a_new_recorder_keeps_the_last_runs_can_log_and_checking_the_path_touches_nothing(tmp_path):
    path = tmp_path / "bus.asc"
    for run in range(2):
        channel = f"bb-restart-{run}-{time.monotonic_ns()}-x"
        CanRecorder.check_path(path)  # as `hitch serve` does before it starts: never truncates a log
        rec = CanRecorder(path, "virtual", channel, keep=3)
        sender = can.Bus(interface="virtual", channel=channel)
        try:
            for k in range(10):
                sender.send(_numbered(100 * run + k))
            deadline = time.monotonic() + 5.0
            while time.monotonic() < deadline and rec.frames_written < 10:
                time.sleep(0.02)
        finally:
            rec.close()
            sender.shutdown()
    assert _numbers(tmp_path / "bus.1.asc") == list(range(10))
    assert _numbers(path) == list(range(100, 110))
    # a run that recorded nothing (its log holds only the header) takes no rotated slot
    CanRecorder(path, "virtual", f"bb-empty-{time.monotonic_ns()}-x", keep=3).close()
    CanRecorder(path, "virtual", f"bb-empty-{time.monotonic_ns()}-y", keep=3).close()
    assert _numbers(tmp_path / "bus.1.asc") == list(range(100, 110))
    assert _numbers(tmp_path / "bus.2.asc") == list(range(10))
    assert not (tmp_path / "bus.3.asc").exists() and _numbers(path) == []


def _block_rotation(folder, name: str) -> None:
    """A non-empty folder where the recorder's rotation must delete a file: the rotation fails."""
    (folder / name).mkdir()
    (folder / name / "keep").write_text("not a log")


def _send_until(channel: str, done, seconds: float = 20.0) -> None:
    sender = can.Bus(interface="virtual", channel=channel)
    try:
        deadline, k = time.monotonic() + seconds, 0
        while not done() and time.monotonic() < deadline:
            for _ in range(500):
                sender.send(_numbered(k))
                k += 1
            time.sleep(0.02)
    finally:
        sender.shutdown()


def test_an_error_that_stops_the_can_log_is_told_once_and_put_out_as_a_numbered_event(tmp_path):
    """A rotation that cannot delete the oldest file ends the recording: before, only the recorder
    knew (its ``error``); now the callback hears it once, as a ``can_log_stopped`` event naming the
    file, and a callback given later hears it at once."""
    channel = f"bb-stop-{time.monotonic_ns()}-x"
    path = tmp_path / "bus.asc"
    _block_rotation(tmp_path, "bus.2.asc")  # keep=2: the rotation deletes bus.2.asc first
    told: list[dict] = []
    outbox = Outbox(on_event=told.append, on_state=lambda m: None)
    with CanRecorder(path, "virtual", channel, max_bytes=100_000, keep=2) as rec:
        announce_can_log_stop(rec, outbox)
        _send_until(channel, lambda: rec.error is not None)
        assert isinstance(rec.error, OSError), rec.error
    assert len(told) == 1, told
    assert told[0]["event"] == "can_log_stopped" and told[0]["seq"] == 1 and told[0]["path"] == str(path)
    assert str(path) in told[0]["message"] and "recording stopped" in told[0]["message"]
    late: list[BaseException] = []
    rec.on_stop(late.append)
    assert late == [rec.error]


@pytest.mark.slow
def test_a_service_announces_that_its_can_log_stopped_and_goes_on(tmp_path):
    """The service (control core in its threads, the twin on the virtual bus) records the bus; when the
    recording fails, every listener gets the ``can_log_stopped`` event and the service keeps running."""
    from tests.integration.service_process import free_port

    channel = f"bb-svc-{time.monotonic_ns()}-x"
    log = tmp_path / "log" / "bus.asc"
    log.parent.mkdir()
    _block_rotation(log.parent, "bus.1.asc")  # keep=1: the rotation deletes bus.1.asc first
    cfg = ServiceConfig(
        listen=[f"tcp/127.0.0.1:{free_port()}"],
        data_dir=tmp_path,
        control_core="thread",
        planning_processes=0,
        can_channel=channel,
        can_log=log,
        can_log_max_mb=0.1,
        can_log_keep=1,
    )
    events: list[dict] = []
    with HitchService(cfg) as svc:
        svc.add_listener("event", events.append)
        stopped = lambda: any(e.get("event") == "can_log_stopped" for e in events)  # noqa: E731
        _send_until(channel, stopped)
        assert stopped(), [e.get("event") for e in events]
        (ev,) = [e for e in events if e.get("event") == "can_log_stopped"]
        assert ev["path"] == str(log) and isinstance(ev["seq"], int)
        assert wait_until(lambda: (svc.latest_state or {}).get("ecu", {}).get("online"))  # the service goes on


def test_can_log_settings_out_of_range_are_refused_by_name():
    with pytest.raises(BlackBoxError, match=r"max_bytes must be an integer in \[100000, 1e11\]"):
        CanRecorder("/tmp/never.asc", "virtual", "bb-never", max_bytes=10)
    with pytest.raises(BlackBoxError, match=r"keep must be an integer in 1\.\.1000"):
        CanRecorder("/tmp/never.asc", "virtual", "bb-never", keep=0)
    with pytest.raises(BlackBoxError, match=r"suffixes: \.asc, \.blf"):
        CanRecorder.check_path("/tmp/never.txt")


def test_the_body_of_every_write_is_kept_and_cut_to_the_same_bound(tmp_path):
    """A field trial: ``hitch/raise`` and ``implements/define`` were logged as "accepted" without what they
    asked; their bodies are kept now, cut to MAX_BODY_CHARS as a goto's."""
    from bridge.service.blackbox import MAX_BODY_CHARS

    path = event_log_path(tmp_path)
    long_name = "t" * (3 * MAX_BODY_CHARS)
    with EventLog(path) as log:
        log.on_request("hitch/raise", "olga", b'{"deadline_ms": 500}', True, {"accepted": True, "motion_id": 4})
        log.on_request("implements/define", "olga", json.dumps({"name": long_name}).encode(), True, {"ok": True})
        log.on_request("goto", "olga", json.dumps({"name": long_name}).encode(), True, {"motion_id": 5})
    raise_, define, goto = [r for r in read_events(path) if r["kind"] == "request"]
    assert json.loads(raise_["request"]) == {"deadline_ms": 500} and raise_["motion_id"] == 4
    assert len(define["request"]) == len(goto["request"]) == MAX_BODY_CHARS
    assert define["request"].startswith('{"name": "ttt')


def test_a_blf_can_log_reaches_the_disk_while_it_records(tmp_path):
    """An incident investigator's trial: a .blf log of a service killed with -9 held none of the last goto's
    frames: the BLF writer kept up to 128 KiB (some 7 s of the bus) in memory. It is written every 0.25 s as the
    text logs are: a copy taken while recording, or after a kill, holds the frames up to then."""
    channel = f"bb-blf-live-{time.monotonic_ns()}-x"
    path = tmp_path / "bus.blf"
    rec = CanRecorder(path, "virtual", channel, keep=2)
    sender = can.Bus(interface="virtual", channel=channel)
    try:
        for k in range(50):
            sender.send(_numbered(k))
        time.sleep(0.4)
        sender.send(_numbered(50))  # a frame after the flush period: the recorder writes what it holds
        deadline = time.monotonic() + 5.0
        seen: list[int] = []
        while time.monotonic() < deadline and len(seen) < 50:
            time.sleep(0.1)
            seen = _numbers(path)  # read while the recorder still runs (as after a kill)
        assert seen[:50] == list(range(50)), seen[:5]
    finally:
        rec.close()
        sender.shutdown()


# ---------------------------------------------------------------------------------------- replay: faults, clock, JSON
_T0 = 1_765_000_000.042  # Unix time of a log's first frame; 42 ms: python-can's ASC header writes it as "…:40.42"


def _neutral_measurement(model: HitchModel, system_state: int = 0) -> tuple[PositionMeasurement, float]:
    scale = SensorScaling(model.profile)
    c = np.rint(scale.counts_min + (model.neutral - scale.si_min) / scale.resolution).astype(int)
    fraction = float((c[0] - scale.counts_min[0]) / (scale.counts_max[0] - scale.counts_min[0]))
    return PositionMeasurement(int(c[1]), int(c[2]), int(c[4]), int(c[3]), system_state), fraction


def _incident_frames(model: HitchModel, t0: float = _T0) -> list[can.Message]:
    """4.5 s of the cylinder ECU (address 169): 0xFF22 at 100 Hz from the first frame, its lift (rear hitch
    status) at 10 Hz only from 0.25 s on, its heartbeat at 10 Hz; measurements silent 1.0–1.6 s and again
    3.0–3.6 s, heartbeats silent 2.0–2.7 s."""
    meas, fraction = _neutral_measurement(model)
    codec = load_codec()
    frames: list[can.Message] = []
    seq = 0

    def silent(t: float, gaps: list[tuple[float, float]]) -> bool:
        return any(a <= t < b for a, b in gaps)

    for k in range(450):
        t = round(0.01 * k, 6)
        out = []
        if not silent(t, [(1.0, 1.6), (3.0, 3.6)]):
            out.append(meas)
            if k % 10 == 5 and t >= 0.25:
                out.append(RearHitchStatus(position=fraction))
        if k % 10 == 0 and not silent(t, [(2.0, 2.7)]):
            out.append(Heartbeat(seq % 251))
            seq += 1
        for p in out:
            frames.append(codec.encode(p, source=169))
            frames[-1].timestamp = t0 + t
    return frames


def _write_log(path, frames: list[can.Message]):
    writer = can.ASCWriter(str(path)) if path.suffix == ".asc" else can.CanutilsLogWriter(str(path), channel="vcan0")
    with writer as w:
        for f in frames:
            w.on_message_received(f)
    return path


@pytest.mark.parametrize("name", ["bus.log", "bus.asc"])
def test_replay_reports_every_raise_and_every_clear_of_a_fault_in_the_logs_time(tmp_path, name):
    """An investigator's log: stale, heartbeat, stale again. The replay's fault reasons only grew, so each
    fault was reported once per file and never cleared (the second stale was not seen at all, a stale
    latched at the log's start hid it). Now every raise and every clear, each at its time."""
    model = HitchModel.from_profile("thesis-t132")
    path = _write_log(tmp_path / name, _incident_frames(model))
    faults = [r for r in replay_can_log(path, model) if r.name in ("fault", "fault_cleared") and not r.log_start]
    assert [(r.name, r.fault) for r in faults] == [
        ("fault", "stale_measurement"),
        ("fault_cleared", "stale_measurement"),
        ("fault", "ecu_heartbeat"),
        ("fault", "stale_measurement"),
        ("fault_cleared", "ecu_heartbeat"),
        ("fault_cleared", "stale_measurement"),
    ]
    # the lift came last at 0.95 s: stale 0.2 s later, in the silence; fresh again with the lift at 1.65 s
    assert faults[0].t_s == pytest.approx(1.15, abs=0.015) and faults[1].t_s == pytest.approx(1.65, abs=1e-6)
    assert faults[2].t_s == pytest.approx(2.2, abs=0.015)  # the heartbeat of 1.9 s was the last one for 0.8 s
    assert faults[3].t_s == pytest.approx(3.15, abs=0.015) and faults[5].t_s == pytest.approx(3.65, abs=1e-6)
    assert "lift" in faults[0].faults[0] and "heartbeat" in faults[2].faults[0].lower()
    assert all(r.source is None and r.timestamp == pytest.approx(_T0 + r.t_s, abs=2e-3) for r in faults)


def test_replay_says_plainly_what_the_log_start_lacked_instead_of_a_false_fault(tmp_path):
    """The log's first 0.25 s carry 0xFF22 but no lift yet: the replay printed "FAULT no valid cylinder positions"
    at 0.2 s — wrong twice: the positions were there, and nothing of the machine had failed; the recording had
    begun before the lift arrived. Now that fault is marked log_start, names what was missing, and its end too."""
    model = HitchModel.from_profile("thesis-t132")
    path = _write_log(tmp_path / "bus.log", _incident_frames(model))
    start = [r for r in replay_can_log(path, model) if r.name in ("fault", "fault_cleared") and r.log_start]
    assert [(r.name, r.fault) for r in start] == [
        ("fault", "stale_measurement"),
        ("fault_cleared", "stale_measurement"),
    ]
    raised, cleared = start
    assert raised.t_s == pytest.approx(0.2, abs=0.015) and cleared.t_s == pytest.approx(0.25, abs=1e-6)
    text = raised.faults[0]
    assert "log start" in text and "lift position" in text and "not a fault of the machine" in text, text
    assert "cylinder positions" not in text, text  # they were heard from the first frame
    assert raised.to_json()["log_start"] is True and raised.to_json()["fault"] == "stale_measurement"


def test_an_ecu_that_never_sends_a_heartbeat_is_a_fault_not_the_logs_start(tmp_path):
    """A review: a heartbeat still missing late in the log was marked log_start ("not a fault of the machine")
    and left out of the count: an ECU that never came up read as no fault. Only the log's first second is its
    start."""
    from bridge.isobus.codec import load_codec

    model = HitchModel.from_profile("thesis-t132")
    hb_id = load_codec().encode(Heartbeat(0), source=169).arbitration_id
    frames = [f for f in _incident_frames(model) if f.arbitration_id != hb_id]
    recs = [r for r in replay_can_log(_write_log(tmp_path / "bus.log", frames), model) if r.name == "fault"]
    hb = [r for r in recs if r.fault == "ecu_heartbeat"]
    assert hb and hb[0].t_s <= 1.0 and hb[0].log_start, [(r.t_s, r.fault, r.log_start) for r in recs]
    assert all(not r.log_start for r in hb if r.t_s > 1.0)
    assert any(r.t_s > 1.0 and not r.log_start for r in hb), [(r.t_s, r.log_start) for r in hb]


def test_replay_records_carry_the_frames_own_unix_time_from_every_format(tmp_path):
    """Replay gave only seconds from the first frame, nothing to line up with `hitch log`. Now each record has
    the frame's Unix time — also from an .asc, whose python-can reader gives times relative to its header's date
    (and reads the date's unpadded milliseconds "40.42" as 0.42 s): absolute, the 42 ms kept. An .asc whose
    header names no date has no wall clock: None, its times still counted from the first frame."""
    model = HitchModel.from_profile("thesis-t132")
    frames = _incident_frames(model)[:30]
    for name in ("bus.log", "bus.asc"):
        recs = [r for r in replay_can_log(_write_log(tmp_path / name, frames), model) if r.source is not None]
        assert len(recs) == len(frames)
        for r, f in zip(recs, frames, strict=True):
            assert r.timestamp == pytest.approx(f.timestamp, abs=1e-5), name
            assert r.to_json()["timestamp"] == r.timestamp and r.to_json()["t"] == r.t_s
            assert r.t_s == pytest.approx(f.timestamp - _T0, abs=1e-6)
    undated = tmp_path / "undated.asc"
    undated.write_text(
        "date someday\nbase hex  timestamps absolute\n 0.500000 1  18FF22A9x       Rx   d 8 00 00 00 00 00 00 00 00\n"
        " 0.600000 1  18FF22A9x       Rx   d 8 00 00 00 00 00 00 00 00\n",
        encoding="utf-8",
    )
    recs = [r for r in replay_can_log(undated, model) if r.source is not None]
    assert [(r.t_s, r.timestamp) for r in recs] == [(0.0, None), (pytest.approx(0.1, abs=1e-6), None)]


def test_replay_json_gives_enums_by_name_and_the_system_state_in_words(tmp_path):
    """--json gave FigureOfMerit as 0 where the text said FULLY_FUNCTIONAL, and 0xFF22's system state only as
    the raw byte; now names in both, and the state's bits in words (3: controllers on, watchdog tripped)."""
    from bridge.isobus.messages import FigureOfMerit, SlopeSensorInformation

    model = HitchModel.from_profile("thesis-t132")
    codec = load_codec()
    ok = FigureOfMerit.FULLY_FUNCTIONAL
    meas, _ = _neutral_measurement(model, system_state=3)
    frames = [
        codec.encode(
            SlopeSensorInformation(0.01, 0.02, 0.0, pitch_merit=ok, roll_merit=ok, pitch_rate_merit=ok), source=226
        ),
        codec.encode(meas, source=169),
    ]
    for k, f in enumerate(frames):
        f.timestamp = _T0 + 0.01 * k
    recs = [r.to_json() for r in replay_can_log(_write_log(tmp_path / "bus.log", frames), model)]
    ssi, ff22 = (r for r in recs if r["source"] is not None)
    assert ssi["fields"]["pitch_merit"] == "FULLY_FUNCTIONAL", ssi
    assert ff22["fields"]["system_state"] == 3 and "watchdog tripped" in ff22["system_state"], ff22
    assert json.loads(json.dumps(recs)) == recs


def test_a_can_log_whose_remote_hub_went_away_ends_its_thread_instead_of_spinning(tmp_path):
    """A field trial: the CAN hub killed mid-motion with can_log set; the recorder's bus raised on every read,
    its on_error told python-can the error was handled, and the notifier thread read again at once — spinning
    at the control core's real-time priority with the GIL: stop refused for 14 s to minutes, the state frozen
    "moving". Now the first error ends the recording's thread (told once), and close() returns at once."""
    import subprocess
    import sys

    code = (
        "import sys, time; from bridge.link.loopback import LoopbackHub; h = LoopbackHub().start(); "
        "print(h.url, flush=True); time.sleep(60)"
    )
    hub = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert hub.stdout is not None
        url = hub.stdout.readline().strip()
        told: list[BaseException] = []
        rec = CanRecorder(tmp_path / "bus.asc", "remote", url)
        try:
            rec.on_stop(told.append)
            assert rec._notifier is not None
            threads = [t for t in rec._notifier._readers if isinstance(t, threading.Thread)]  # python-can's thread
            assert threads and threads[0].is_alive()
            hub.kill()  # as the trial's kill -9
            hub.wait(5.0)
            assert wait_until(lambda: not threads[0].is_alive(), 5.0), (rec.error, told)
            assert rec.error is not None and told == [rec.error]
        finally:
            t0 = time.monotonic()
            rec.close()
            assert time.monotonic() - t0 < 1.0
    finally:
        hub.kill()
        hub.wait(5.0)


class _DyingBus(can.BusABC):
    """60 frames, then every read raises (a remote hub that went away)."""

    def __init__(self) -> None:
        self.k = 0
        super().__init__(channel="dying")

    def _recv_internal(self, timeout):
        self.k += 1
        time.sleep(0.002)
        if self.k <= 60:
            return can.Message(arbitration_id=0x18FF22A9, data=bytes(8), timestamp=time.time()), False
        raise BrokenPipeError(32, "Broken pipe")

    def send(self, msg, timeout=None):
        pass


@pytest.mark.parametrize("clock_steps_back", [False, True])
def test_a_can_log_ended_by_an_error_is_complete_when_close_returns(tmp_path, monkeypatch, clock_steps_back):
    """A review of the fix above: close() during the error's own stop returned at once, the writer still closing
    (a process exiting then cut the file short); and a step back of the wall clock between python-can's two
    readings in its stop had it join its own thread (RuntimeError, swallowed): the file was never closed."""
    import can.notifier

    import bridge.link.realtime as realtime
    from bridge.service import blackbox

    monkeypatch.setattr(realtime, "open_bus", lambda interface, channel=None, **kw: _DyingBus())
    slow_stop, stopped = blackbox._SizedLog.stop, threading.Event()

    def stop(self):
        time.sleep(0.3)  # a slow disk
        slow_stop(self)
        stopped.set()

    monkeypatch.setattr(blackbox._SizedLog, "stop", stop)
    if clock_steps_back:

        class SteppingTime:  # on the notifier's thread, every second reading is 1 s back
            n = 0

            def __getattr__(self, name):
                return getattr(time, name)

            def time(self):
                if threading.current_thread().name.startswith("Notifier"):
                    self.n += 1
                    return time.time() - (1.0 if self.n % 2 == 0 else 0.0)
                return time.time()

        monkeypatch.setattr(can.notifier, "time", SteppingTime())
    rec = CanRecorder(tmp_path / "bus.asc", "virtual", "x")
    assert wait_until(lambda: rec.error is not None, 5.0)
    rec.close()
    assert stopped.is_set()
    assert (tmp_path / "bus.asc").read_text().rstrip().endswith("End TriggerBlock")
