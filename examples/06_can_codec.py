"""The CAN codec: a position reference in SI -> AD counts -> a J1939 frame, and back.

The planner sends the cylinder ECU five 10-bit AD counts (PGN 0xFF21); the DBC file
``bridge/isobus/hitch.dbc`` defines the bit layout. Decoding rejects wrong lengths, unknown
PGNs and out-of-range values with a CodecError saying why.
"""

import can

from bridge import CodecError, PositionCounts, decode_frame, encode_position_reference
from planner import ACTUATOR_NAMES, ACTUATOR_UNITS, HitchModel, SensorScaling

model = HitchModel.from_profile()
scaling = SensorScaling(model.profile)  # thesis tables 3-1 and 3-2: SI <-> counts

q = model.neutral  # actuators in SI: lift [rad], tilt, top, left, right [m]
counts = PositionCounts(*(int(c) for c in scaling.to_counts(q)))
print(
    "reference: "
    + ", ".join(
        f"{n} {v:.4f} {ACTUATOR_UNITS[n]} -> {c} counts"
        for n, v, c in zip(ACTUATOR_NAMES, q, counts.as_tuple(), strict=True)
    )
)

frame = encode_position_reference(counts)
print(f"frame: id 0x{frame.arbitration_id:08X} (29-bit), data {frame.data.hex(' ')}")

decoded = decode_frame(frame)
print(f"decoded: PGN 0x{decoded.ident.pgn:04X} from source address {decoded.source_address}: {decoded.payload}")
assert isinstance(decoded.payload, PositionCounts)  # the payload class follows from the frame's PGN
back = scaling.to_si(decoded.payload.as_tuple())
print(
    "quantisation error: "
    + ", ".join(
        f"{n} {1e3 * (b - v):+.2f} {'mrad' if n == 'lift' else 'mm'}"
        for n, b, v in zip(ACTUATOR_NAMES, back, q, strict=True)
    )
)

# A frame cut short is rejected, not guessed at.
short = can.Message(arbitration_id=frame.arbitration_id, is_extended_id=True, data=frame.data[:4])
try:
    decode_frame(short)
except CodecError as exc:
    print(f"short frame: {exc}")
