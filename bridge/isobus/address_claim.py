"""ISO 11783-5 / SAE J1939-81 NAME and address claiming as a pure state machine.

A control function claims a source address by broadcasting Address Claimed
(PGN 60928) with its 64-bit NAME, and may use the address once 250 ms pass
without a contending claim (thesis section 1.3, ISO 11783-5). When two control
functions claim the same address the one with the numerically lower NAME keeps
it; the loser either claims another address (if arbitrary address capable) or
sends Cannot Claim — Address Claimed from the null address 254 — and stays
silent. A Request (PGN 59904) for PGN 60928 is answered with our claim, at most one claim every
``answer_interval_s`` (:data:`REQUEST_ANSWER_INTERVAL_S`, 100 ms): a request that comes sooner after our last
claim is answered when the interval is over, by one claim for every request that came meanwhile (a claim goes to
every node). A node flooding requests (a fuzz trial: 1000 requests/s drew 1000 claims/s, most of a 250 kbit/s
bus) so gets at most 10 claims a second, and every request is still answered within 100 ms — well inside the
250 ms a node re-checking a lost address waits for the holder's answer, and within the 200 ms J1939-21 gives a
responder. Without an address (Cannot Claim) the answer to a global request also waits J1939-81's pseudo-random
delay (NAME mod 154 ms): within the larger of the two. Claims in a contention (a defence, a claim of another address,
Cannot Claim) are never held back; each one also answers the requests before it.

A control function that lost its address may check whether the winner is still there
(``recheck_s``): every ``recheck_s`` it asks the address (a Request for Address Claimed
from the null address, which J1939-81 allows a node without an address to send) and, when
no claim with a NAME lower than ours answers within the contention window, claims its
preferred address again (a spoofed or departed claimant does not hold it for ever; a real
one answers, and the claimer stays in "cannot claim"). :attr:`AddressClaimer.holder` names
the NAME that holds it meanwhile.

:class:`AddressClaimer` owns no thread and no clock: feed it received frames with
``handle(frame, now_s)`` and call ``poll(now_s)`` periodically; both return the
frames to transmit.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import can

from bridge.isobus.codec import AddressClaimed, CodecError, RequestPgn, decode_frame, encode
from bridge.isobus.j1939 import (
    GLOBAL_ADDRESS,
    NULL_ADDRESS,
    PGN_ADDRESS_CLAIMED,
    PGN_REQUEST,
    PLANNER_ADDRESS,
    J1939Error,
    decode_id,
)
from planner.errors import HitchInputError

__all__ = [
    "AddressClaimError",
    "AddressClaimer",
    "CLAIM_WAIT_S",
    "ClaimState",
    "Name",
    "REQUEST_ANSWER_INTERVAL_S",
    "SELF_CONFIGURABLE_RANGE",
    "cylinder_ecu_name",
    "planner_name",
]

CLAIM_WAIT_S = 0.25
"""Time without contention after which a claimed address may be used, s."""
REQUEST_ANSWER_INTERVAL_S = 0.1
"""A Request for Address Claimed is answered at most this often (later ones wait, then share one answer), s."""
SELF_CONFIGURABLE_RANGE = (128, 247)
"""Addresses an arbitrary-address-capable control function may pick (J1939-81)."""


class AddressClaimError(HitchInputError):
    """A NAME field, address or claim setting outside its allowed range."""


_LAYOUT = (  # (field, first bit, length) of the 64-bit NAME, J1939-81 / ISO 11783-5
    ("identity_number", 0, 21),
    ("manufacturer_code", 21, 11),
    ("ecu_instance", 32, 3),
    ("function_instance", 35, 5),
    ("function", 40, 8),
    ("reserved", 48, 1),
    ("vehicle_system", 49, 7),
    ("vehicle_system_instance", 56, 4),
    ("industry_group", 60, 3),
    ("arbitrary_address_capable", 63, 1),
)


@dataclass(frozen=True)
class Name:
    """An ISO 11783-5 / J1939-81 NAME; on contention the lower :attr:`value` wins.

    Attributes:
        identity_number: 21 bits, unique per manufacturer.
        manufacturer_code: 11 bits, assigned by SAE / ISO (0 here: unassigned).
        ecu_instance: 3 bits.
        function_instance: 5 bits.
        function: 8 bits; 130 = rear hitch control (industry group 2, vehicle
            system 1).
        vehicle_system: 7 bits ("device class"); 1 = tractor in industry group 2.
        vehicle_system_instance: 4 bits.
        industry_group: 3 bits; 2 = agricultural and forestry equipment.
        arbitrary_address_capable: may move to another address on contention.
        reserved: 1 bit, 0.
    """

    identity_number: int
    manufacturer_code: int = 0
    ecu_instance: int = 0
    function_instance: int = 0
    function: int = 130
    vehicle_system: int = 1
    vehicle_system_instance: int = 0
    industry_group: int = 2
    arbitrary_address_capable: bool = False
    reserved: int = 0

    def __post_init__(self) -> None:
        if not isinstance(self.arbitrary_address_capable, bool):
            raise AddressClaimError(
                f"Name.arbitrary_address_capable must be a bool, got {self.arbitrary_address_capable!r}"
            )
        for field, _start, length in _LAYOUT[:-1]:
            item = getattr(self, field)
            if isinstance(item, bool) or not isinstance(item, int) or not 0 <= item < 1 << length:
                raise AddressClaimError(f"Name.{field} must be an integer in 0..{(1 << length) - 1}, got {item!r}")

    @property
    def value(self) -> int:
        """The 64-bit NAME as sent little-endian in Address Claimed."""
        return sum(int(getattr(self, field)) << start for field, start, _ in _LAYOUT)

    @classmethod
    def from_int(cls, value: int) -> Name:
        """Split a 64-bit NAME into its fields."""
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < 1 << 64:
            raise AddressClaimError(f"NAME must be an integer in 0..2^64-1, got {value!r}")
        part = {f: (value >> start) & ((1 << n) - 1) for f, start, n in _LAYOUT}
        return cls(
            identity_number=part["identity_number"],
            manufacturer_code=part["manufacturer_code"],
            ecu_instance=part["ecu_instance"],
            function_instance=part["function_instance"],
            function=part["function"],
            vehicle_system=part["vehicle_system"],
            vehicle_system_instance=part["vehicle_system_instance"],
            industry_group=part["industry_group"],
            arbitrary_address_capable=bool(part["arbitrary_address_capable"]),
            reserved=part["reserved"],
        )


def planner_name(identity_number: int = 1, *, arbitrary_address_capable: bool = False) -> Name:
    """The planner's NAME: agricultural tractor rear hitch control, ECU instance 0."""
    return Name(identity_number, ecu_instance=0, arbitrary_address_capable=arbitrary_address_capable)


def cylinder_ecu_name(identity_number: int = 2) -> Name:
    """The cylinder ECU's NAME: rear hitch control, ECU instance 1, fixed address."""
    return Name(identity_number, ecu_instance=1)


class ClaimState(Enum):
    """Where an :class:`AddressClaimer` is."""

    IDLE = "idle"  # not started
    CLAIMING = "claiming"  # claim sent, waiting 250 ms for contention
    CLAIMED = "claimed"  # address may be used
    CANNOT_CLAIM = "cannot claim"  # lost; silent except Cannot Claim answers


class AddressClaimer:
    """Claims and defends one source address for ``name``.

    Args:
        name: our NAME.
        preferred_address: the address to claim first (thesis: planner 166,
            cylinder ECU 169).
        wait_s: contention window after a claim, s (ISO 11783-5: 0.25); also how long an asked
            holder of the preferred address has to answer.
        recheck_s: after losing the preferred address, ask its holder this often and claim it
            again when nobody with a lower NAME answers (module docstring); None (default): stay
            in "cannot claim" until :meth:`start`.
        answer_interval_s: the shortest time between two claims that answer Requests for Address
            Claimed (module docstring; default :data:`REQUEST_ANSWER_INTERVAL_S`); less than ``wait_s``, so
            that a holder asked by a node re-checking its lost address answers within that node's window.
    """

    def __init__(
        self,
        name: Name,
        preferred_address: int = PLANNER_ADDRESS,
        *,
        wait_s: float = CLAIM_WAIT_S,
        recheck_s: float | None = None,
        answer_interval_s: float = REQUEST_ANSWER_INTERVAL_S,
    ) -> None:
        if (
            isinstance(preferred_address, bool)
            or not isinstance(preferred_address, int)
            or not (0 <= preferred_address <= 253)
        ):
            raise AddressClaimError(f"preferred_address must be in 0..253, got {preferred_address!r}")
        if not wait_s > 0:
            raise AddressClaimError(f"wait_s must be > 0 s, got {wait_s!r}")
        if recheck_s is not None and (
            isinstance(recheck_s, bool) or not isinstance(recheck_s, (int, float)) or not 0 < recheck_s <= 3600
        ):
            raise AddressClaimError(f"recheck_s must be None or a number of seconds in (0, 3600], got {recheck_s!r}")
        if (
            isinstance(answer_interval_s, bool)
            or not isinstance(answer_interval_s, (int, float))
            or not 0 <= answer_interval_s < wait_s
        ):
            raise AddressClaimError(
                f"answer_interval_s must be a number of seconds in [0, wait_s = {wait_s!r}), got {answer_interval_s!r}"
            )
        self._answer_interval_s = float(answer_interval_s)
        self._answered_s = -float("inf")  # when our last claim (or Cannot Claim) went out
        self._answer_due_s: float | None = None  # when a held-back answer to a request goes out
        self._recheck_s = None if recheck_s is None else float(recheck_s)
        self._recheck_due_s = float("inf")  # when to ask the holder of the preferred address next
        self._asked_s: float | None = None  # when we asked it (an answer is awaited)
        self._name = name
        self._preferred = preferred_address
        self._wait_s = float(wait_s)
        self._state = ClaimState.IDLE
        self._address: int | None = None
        self._deadline_s = 0.0
        self._peers: dict[int, Name] = {}

    @property
    def name(self) -> Name:
        """Our NAME."""
        return self._name

    @property
    def state(self) -> ClaimState:
        """Current state."""
        return self._state

    @property
    def address(self) -> int | None:
        """The address being claimed or held, ``None`` when idle or cannot claim."""
        return self._address

    @property
    def claimed(self) -> bool:
        """True once the address may be used for normal traffic."""
        return self._state is ClaimState.CLAIMED

    @property
    def preferred_address(self) -> int:
        """The address we claim (and claim again after losing it, with ``recheck_s``)."""
        return self._preferred

    @property
    def holder(self) -> Name | None:
        """While we cannot claim: the NAME that holds our preferred address (last heard claiming it), else
        None."""
        return self._peers.get(self._preferred) if self._state is ClaimState.CANNOT_CLAIM else None

    @property
    def peers(self) -> dict[int, Name]:
        """Other control functions seen claiming, by address (a copy)."""
        return dict(self._peers)

    @staticmethod
    def who_is_there() -> can.Message:
        """A global Request for Address Claimed from the null address (J1939-81: a node without an address may
        send it): every node on the bus answers with its claim, so :attr:`peers` learns also the nodes that
        claimed before we started (an ECU powered up first; its NAME is the machine's identity)."""
        return encode(RequestPgn(PGN_ADDRESS_CLAIMED), source=NULL_ADDRESS, destination=GLOBAL_ADDRESS)

    def start(self, now_s: float) -> list[can.Message]:
        """Send our first claim for the preferred address."""
        self._peers.clear()
        self._answer_due_s = None
        self._answered_s = -float("inf")
        self._recheck_due_s = float("inf")
        return self._claim(self._preferred, now_s)

    def announce(self) -> list[can.Message]:
        """Our claim once more, to every node (J1939-81: a node that receives a message other than Address
        Claimed with its own source address sends its claim, so that the other node sees the contention);
        [] unless we hold or are claiming an address."""
        if self._address is None or self._state not in (ClaimState.CLAIMING, ClaimState.CLAIMED):
            return []
        return [encode(AddressClaimed(self._name.value), source=self._address, destination=GLOBAL_ADDRESS)]

    def poll(self, now_s: float) -> list[can.Message]:
        """Advance time: finish the contention window, release delayed answers, check the holder of a lost
        address (``recheck_s``)."""
        if self._state is ClaimState.CLAIMING and now_s >= self._deadline_s:
            self._state = ClaimState.CLAIMED
        due: list[can.Message] = []
        if self._answer_due_s is not None and now_s >= self._answer_due_s:
            due = self._answer(now_s)
        if self._state is ClaimState.CANNOT_CLAIM and self._recheck_s is not None:
            if self._asked_s is not None and now_s >= self._asked_s + self._wait_s:
                self._peers.pop(self._preferred, None)  # nobody with a lower NAME answered: it is free
                return [*due, *self._claim(self._preferred, now_s)]
            if self._asked_s is None and now_s >= self._recheck_due_s:
                self._asked_s = now_s
                self._recheck_due_s = now_s + self._recheck_s
                ask = encode(RequestPgn(PGN_ADDRESS_CLAIMED), source=NULL_ADDRESS, destination=self._preferred)
                return [*due, ask]
        return due

    def handle(self, frame: can.Message, now_s: float) -> list[can.Message]:
        """Process one received frame; other PGNs and malformed frames are ignored."""
        if self._state is ClaimState.IDLE or not frame.is_extended_id:
            return []
        try:
            pgn = decode_id(frame.arbitration_id).pgn
        except J1939Error:
            return []
        if pgn not in (PGN_ADDRESS_CLAIMED, PGN_REQUEST):
            return []
        try:
            decoded = decode_frame(frame)
        except CodecError:
            return []
        if isinstance(decoded.payload, RequestPgn):
            return self._on_request(decoded.payload.pgn, decoded.ident.destination_address, now_s)
        if isinstance(decoded.payload, AddressClaimed):
            other = Name.from_int(decoded.payload.name)
            return self._on_claim(decoded.source_address, other, now_s)
        return []

    def _claim_frame(self, source: int, now_s: float) -> can.Message:
        """Our claim of ``source`` (Cannot Claim from the null address), sent at ``now_s``: it answers every
        request before it."""
        self._answered_s = now_s
        self._answer_due_s = None
        return encode(AddressClaimed(self._name.value), source=source, destination=GLOBAL_ADDRESS)

    def _claim(self, address: int, now_s: float) -> list[can.Message]:
        self._asked_s = None
        self._address = address
        self._state = ClaimState.CLAIMING
        self._deadline_s = now_s + self._wait_s
        return [self._claim_frame(address, now_s)]

    def _give_up(self, now_s: float) -> list[can.Message]:
        self._state = ClaimState.CANNOT_CLAIM
        self._address = None
        self._asked_s = None
        if self._recheck_s is not None:
            self._recheck_due_s = now_s + self._recheck_s
        return [self._claim_frame(NULL_ADDRESS, now_s)]

    def _answer(self, now_s: float) -> list[can.Message]:
        """The answer to the requests held back until now: our claim as it stands now (Cannot Claim while we
        cannot claim, nothing before :meth:`start`)."""
        self._answer_due_s = None
        if self._state is ClaimState.CANNOT_CLAIM:
            return [self._claim_frame(NULL_ADDRESS, now_s)]
        if self._address is None:
            return []
        return [self._claim_frame(self._address, now_s)]

    def _on_request(self, pgn: int, destination: int, now_s: float) -> list[can.Message]:
        """Answer a Request for Address Claimed at once, or — within ``answer_interval_s`` of our last claim —
        when the interval is over (one answer for every request meanwhile: module docstring)."""
        if pgn != PGN_ADDRESS_CLAIMED:
            return []
        earliest_s = now_s
        if self._state is ClaimState.CANNOT_CLAIM:
            if destination != GLOBAL_ADDRESS:
                return []
            # J1939-81: pseudo-random 0..153 ms delay against simultaneous answers.
            earliest_s += (self._name.value % 154) / 1000.0
        elif self._address is None or destination not in (GLOBAL_ADDRESS, self._address):
            return []
        if self._answer_due_s is not None:
            return []  # an answer is on its way already: it answers this request too
        due_s = max(earliest_s, self._answered_s + self._answer_interval_s)
        if due_s > now_s:
            self._answer_due_s = due_s
            return []
        return self._answer(now_s)

    def _on_claim(self, source: int, other: Name, now_s: float) -> list[can.Message]:
        if source == NULL_ADDRESS:
            return []  # someone else's Cannot Claim
        if other == self._name:
            return []  # our own claim seen again (echo)
        for address, peer in list(self._peers.items()):
            if peer == other:
                del self._peers[address]  # that NAME moved
        self._peers[source] = other
        if self._state is ClaimState.CANNOT_CLAIM:
            if source == self._preferred and self._asked_s is not None:
                if other.value < self._name.value:
                    self._asked_s = None  # the holder answered: it still holds the address
                else:  # a higher NAME holds it now: we win the contention
                    return self._claim(self._preferred, now_s)
            return []
        if source != self._address:
            return []
        if self._name.value < other.value:
            # We win: defend the address; a claim in progress restarts its window.
            if self._state is ClaimState.CLAIMING:
                self._deadline_s = now_s + self._wait_s
            return [self._claim_frame(self._address, now_s)]
        if not self._name.arbitrary_address_capable:
            return self._give_up(now_s)
        low, high = SELF_CONFIGURABLE_RANGE
        free = [a for a in range(low, high + 1) if a not in self._peers]
        if not free:
            return self._give_up(now_s)
        after = [a for a in free if a > source]
        return self._claim((after or free)[0], now_s)
