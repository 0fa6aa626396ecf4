"""CAN logs whose frames are stamped a little out of time order (several senders stamping their own times,
interleaved through the CAN hub): the recorder writes them in time order, the replay takes them in file order.

An integrator's report: ``hitch replay bus.asc`` exited 2 on the product's own log ("frame 65086 … goes back in
time"; 6 reversals of up to 15 ms in 150 000 frames) that python-can reads fine. The hub stamps a frame when a
sender's thread hands it on, before it puts it into each client's queue; another sender's thread can stamp and
deliver in between.
"""

from __future__ import annotations

import time

import can
import numpy as np
import pytest

from bridge.isobus.codec import load_codec
from bridge.isobus.messages import Heartbeat, PositionMeasurement, RearHitchStatus
from bridge.service.blackbox import BlackBoxError, CanRecorder, replay_can_log
from planner.model.kinematics import HitchModel
from planner.model.sensors import SensorScaling

T0 = 1_765_000_000.0
#: the frames (tick, message) whose stamp lies 15 ms before the frame written just before them: each a lift
#: frame, written after its tick's measurement (stamped at the tick) but stamped 15 ms before the tick
JITTERED_TICKS = (12, 40, 77, 103, 150, 181)
JITTER_S = 0.015
#: the replay's closing record of frames out of time order, and the documented limit of a step back taken as
#: jitter [s] (docs: "up to 0.25 s back")
OUT_OF_ORDER = "out_of_order"
MAX_OUT_OF_ORDER_S = 0.25

_WRITERS = {".asc": can.ASCWriter, ".log": can.CanutilsLogWriter, ".blf": can.BLFWriter}


def _ecu_frames() -> list[can.Message]:
    """2 s of a healthy cylinder ECU (169): 0xFF22 and the lift at 100 Hz, its heartbeat at 10 Hz — in file
    order, the lift of each tick of :data:`JITTERED_TICKS` stamped :data:`JITTER_S` before its tick."""
    model = HitchModel.from_profile("thesis-t132")
    scale = SensorScaling(model.profile)
    c = np.rint(scale.counts_min + (model.neutral - scale.si_min) / scale.resolution).astype(int)
    fraction = float((c[0] - scale.counts_min[0]) / (scale.counts_max[0] - scale.counts_min[0]))
    codec = load_codec()
    frames = []
    for k in range(200):
        t = T0 + 0.01 * k
        out = [PositionMeasurement(int(c[1]), int(c[2]), int(c[4]), int(c[3]), 1), RearHitchStatus(position=fraction)]
        out += [Heartbeat(k // 10)] if k % 10 == 0 else []
        for p in out:
            m = codec.encode(p, source=169)
            m.timestamp = t - (JITTER_S if k in JITTERED_TICKS and isinstance(p, RearHitchStatus) else 0.0)
            frames.append(m)
    return frames


def _write(path, frames: list[can.Message]) -> None:
    with _WRITERS[path.suffix](str(path)) as w:
        for m in frames:
            w.on_message_received(m)


@pytest.mark.parametrize("suffix", [".asc", ".log", ".blf"])
def test_replay_takes_frames_stamped_a_little_back_in_file_order_and_counts_them(tmp_path, suffix):
    """Was: BlackBoxError "frame 27 … goes back in time" (exit 2). Now every frame is replayed in the file's
    order, the jittered ones at the time of the frame before them, no fault, and a last record counts them."""
    frames = _ecu_frames()
    path = tmp_path / f"bus{suffix}"
    _write(path, frames)
    recs = list(replay_can_log(path, HitchModel.from_profile("thesis-t132")))
    assert [r.name for r in recs if r.name in ("fault", "fault_cleared")] == [], [r.faults for r in recs]
    decoded = [r for r in recs if r.source is not None]
    assert [r.name for r in decoded] == [type(load_codec().decode_frame(m).payload).__name__ for m in frames]
    assert all(not r.error for r in decoded)
    times = [r.t_s for r in decoded]
    assert times == sorted(times), "the replay went back in time"
    moved = [i for i, m in enumerate(frames) if i and m.timestamp < frames[i - 1].timestamp]
    assert len(moved) == len(JITTERED_TICKS)
    for i in moved:  # taken at the time of the frame written before it (its tick), not its own 15 ms before
        assert decoded[i].t_s == pytest.approx(frames[i - 1].timestamp - T0, abs=2e-6), i
        assert decoded[i].timestamp == pytest.approx(frames[i - 1].timestamp, abs=2e-6), i
    last = recs[-1]
    assert last.name == OUT_OF_ORDER and last.source is None, last
    assert last.fields["frames"] == len(JITTERED_TICKS)
    assert last.fields["max_back_s"] == pytest.approx(JITTER_S, abs=2e-6)
    assert last.fields["first_frame"] == moved[0] + 1  # numbered from 1, as the error names frames
    assert last.faults == ("6 frames out of time order by up to 15.0 ms, taken in file order",)
    assert last.t_s == pytest.approx(times[-1], abs=1e-9)
    assert sum(r.name == OUT_OF_ORDER for r in recs) == 1


def _in_time_order(frames: list[can.Message]) -> list[can.Message]:
    """``frames`` with the jittered stamps raised to their tick's time."""
    for i, m in enumerate(frames):
        m.timestamp = max(m.timestamp, frames[i - 1].timestamp if i else m.timestamp)
    return frames


def test_replay_of_a_log_in_time_order_has_no_out_of_order_record(tmp_path):
    frames = _in_time_order(_ecu_frames())
    path = tmp_path / "bus.log"
    _write(path, frames)
    recs = list(replay_can_log(path, HitchModel.from_profile("thesis-t132")))
    assert [r for r in recs if r.name == OUT_OF_ORDER] == []
    assert len(recs) == len(frames)


@pytest.mark.parametrize(("back_s", "refused"), [(MAX_OUT_OF_ORDER_S - 0.01, False), (MAX_OUT_OF_ORDER_S + 0.01, True)])
def test_a_step_back_beyond_the_jitter_limit_is_refused_naming_the_frame_and_both_times(tmp_path, back_s, refused):
    """Two logs put together (the second begins before the first ended) or a damaged file are not jitter:
    refused with the frame's number and both times; a step back within the limit is taken."""
    frames = _in_time_order(_ecu_frames()[:100])
    frames[60].timestamp = frames[59].timestamp - back_s
    path = tmp_path / "joined.log"
    _write(path, frames)
    model = HitchModel.from_profile("thesis-t132")
    if refused:
        expect = (
            rf"joined\.log: frame 61 at {frames[60].timestamp:.6f} s goes back in time from "
            rf"{frames[59].timestamp:.6f} s, by {back_s:.6f} s"
        )
        with pytest.raises(BlackBoxError, match=expect):
            list(replay_can_log(path, model))
    else:
        last = list(replay_can_log(path, model))[-1]
        assert last.name == OUT_OF_ORDER and last.fields["frames"] == 1
        assert last.fields["max_back_s"] == pytest.approx(back_s, abs=2e-6)


def _numbered(k: int, t: float) -> can.Message:
    return can.Message(timestamp=t, arbitration_id=0x18FEEEAB, is_extended_id=True, data=k.to_bytes(4, "big"))


@pytest.mark.parametrize("suffix", [".asc", ".log"])
def test_recorder_writes_frames_the_hub_delivers_out_of_time_order_in_time_order(tmp_path, suffix):
    """The hub's stamps reach the recorder interleaved (here a sender that keeps its own stamps, as the hub's
    threads hand them on): the recorder wrote them as they came, back in time; now in the order received, each
    stamped before the latest one written at that latest time, and counted. A clock set back by seconds (no
    jitter) is not taken for jitter: not counted, and not held at the latest time (what python-can's writers make
    of a frame before a file's first is theirs: ASC writes its absolute time, candump its first frame's)."""
    channel = f"replay-order-rec-{suffix[1:]}"
    path = tmp_path / f"bus{suffix}"
    rec = CanRecorder(path, "virtual", channel)
    sender = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
    # received order 0..7; stamps: 4 is 12 ms and 5 is 3 ms before 3's; 7 is 10 s back (a clock set back)
    stamps = [0.000, 0.010, 0.020, 0.030, 0.018, 0.027, 0.040, -9.960]
    try:
        for k, s in enumerate(stamps):
            sender.send(_numbered(k, T0 + s))
        deadline = time.monotonic() + 5.0
        while rec.frames_written < len(stamps) and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        rec.close()
        sender.shutdown()
    back = [m for m in can.LogReader(str(path)) if not m.is_error_frame]
    assert [int.from_bytes(m.data[:4], "big") for m in back] == list(range(len(stamps)))  # as received
    got = [round(m.timestamp - back[0].timestamp, 6) for m in back[:7]]
    assert got == [0.0, 0.01, 0.02, 0.03, 0.03, 0.03, 0.04], got
    assert round(back[7].timestamp - back[0].timestamp, 6) != 0.04
    assert rec.frames_out_of_order == 2
    assert rec.max_out_of_order_s == pytest.approx(0.012, abs=1e-6)
