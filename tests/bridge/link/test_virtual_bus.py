"""The in-process bus (:class:`bridge.link.virtual.InProcessBus`): python-can's virtual bus with a
field-by-field frame copy. What a receiver gets must be what ``VirtualBus.send``'s deep copy gives."""

from __future__ import annotations

import uuid

import can
import pytest

from bridge.link.realtime import open_bus
from bridge.link.virtual import InProcessBus

_FIELDS = (
    "arbitration_id",
    "is_extended_id",
    "is_remote_frame",
    "is_error_frame",
    "channel",
    "dlc",
    "data",
    "is_fd",
    "is_rx",
    "bitrate_switch",
    "error_state_indicator",
)


def _channel() -> str:
    return f"test-inprocess-{uuid.uuid4().hex}"


def _frames() -> list[can.Message]:
    return [
        can.Message(arbitration_id=0x18FF22A9, is_extended_id=True, data=bytes([1, 2, 3, 4, 5, 6, 7, 0xFF])),
        can.Message(arbitration_id=0x123, is_extended_id=False, data=b"\x00"),
        can.Message(arbitration_id=0x0CF0E4A6, is_extended_id=True, data=b""),
        can.Message(arbitration_id=0x18EAFFFE, is_extended_id=True, is_remote_frame=True, dlc=3),
        can.Message(
            arbitration_id=0x1ABCDE, is_extended_id=True, is_fd=True, bitrate_switch=True, data=bytes(range(12))
        ),
        can.Message(is_error_frame=True, error_state_indicator=True),
    ]


def _received(sender_cls: type, **kwargs) -> list[can.Message]:
    ch = _channel()
    tx, rx = sender_cls(channel=ch, **kwargs), can.Bus(interface="virtual", channel=ch)
    try:
        for m in _frames():
            tx.send(m)
        return [rx.recv(1.0) for _ in _frames()]
    finally:
        tx.shutdown()
        rx.shutdown()


def test_a_receiver_gets_what_python_cans_virtual_bus_would_give():
    from can.interfaces.virtual import VirtualBus

    ours, theirs = _received(InProcessBus), _received(VirtualBus)
    for a, b in zip(ours, theirs, strict=True):
        assert a is not None and b is not None
        assert {f: getattr(a, f) for f in _FIELDS if f != "channel"} == {
            f: getattr(b, f) for f in _FIELDS if f != "channel"
        }
        assert a.is_rx and type(a.data) is type(b.data)


def test_each_receiver_gets_its_own_copy_stamped_at_the_send():
    ch = _channel()
    tx = InProcessBus(channel=ch)
    rx1, rx2 = can.Bus(interface="virtual", channel=ch), InProcessBus(channel=ch)
    try:
        msg = can.Message(arbitration_id=0x18FF21A6, is_extended_id=True, data=bytearray(b"\x01\x02"), timestamp=5.0)
        tx.send(msg)
        msg.data[0] = 0xEE  # the sender reuses its frame: the copies must not change
        a, b = rx1.recv(1.0), rx2.recv(1.0)
        assert a is not None and b is not None and a is not b and a is not msg
        assert bytes(a.data) == bytes(b.data) == b"\x01\x02"
        a.data[1] = 0x77
        assert bytes(b.data) == b"\x01\x02"
        assert a.timestamp == b.timestamp != 5.0  # the send time, not the sender's stamp
        assert a.channel == b.channel == ch
        assert tx.recv(0.0) is None  # not our own frame
    finally:
        for bus in (tx, rx1, rx2):
            bus.shutdown()


def test_own_frames_and_preserved_timestamps_as_python_can_defines_them():
    ch = _channel()
    tx = InProcessBus(channel=ch, receive_own_messages=True, preserve_timestamps=True)
    try:
        tx.send(can.Message(arbitration_id=0x100, is_extended_id=False, data=b"\x09", timestamp=12.5))
        own = tx.recv(1.0)
        assert own is not None and own.timestamp == 12.5 and not own.is_rx and bytes(own.data) == b"\x09"
    finally:
        tx.shutdown()


def test_a_full_receiver_queue_is_an_error_and_a_closed_bus_refuses_to_send():
    ch = _channel()
    tx, rx = InProcessBus(channel=ch), InProcessBus(channel=ch, rx_queue_size=1)
    try:
        tx.send(can.Message(arbitration_id=1, is_extended_id=False))
        with pytest.raises(can.CanOperationError):
            tx.send(can.Message(arbitration_id=2, is_extended_id=False), timeout=0.01)
    finally:
        rx.shutdown()
        tx.shutdown()
    with pytest.raises(can.CanOperationError):
        tx.send(can.Message(arbitration_id=3, is_extended_id=False))


def test_open_bus_gives_the_in_process_bus_for_virtual_with_the_receive_filters():
    ch = _channel()
    rx = open_bus("virtual", ch, can_filters=[{"can_id": 0x100, "can_mask": 0x7FF, "extended": False}])
    tx = can.Bus(interface="virtual", channel=ch)  # python-can's own bus on the same channel
    try:
        assert isinstance(rx, InProcessBus)
        tx.send(can.Message(arbitration_id=0x200, is_extended_id=False))
        tx.send(can.Message(arbitration_id=0x100, is_extended_id=False, data=b"\x01"))
        got = rx.recv(1.0)
        assert got is not None and got.arbitration_id == 0x100 and rx.recv(0.0) is None
    finally:
        rx.shutdown()
        tx.shutdown()
