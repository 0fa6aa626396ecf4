"""HitchClient sends what a Python program holds, or says why not (a fleet trial: ``numpy.float32`` raised a raw
"Object of type float32 is not JSON serializable", ``goto([0.1])`` a raw TypeError). Truth: what a stand-in
service on 127.0.0.1 receives."""

from __future__ import annotations

import json

import numpy as np
import pytest
import zenoh

from bench._common import free_port
from bridge.service.client import ClientError, HitchClient


@pytest.fixture
def echo():
    """A stand-in service: ``hitch/goto`` answers with the payload it received."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    c = zenoh.Config()
    c.insert_json5("mode", '"peer"')
    c.insert_json5("listen/endpoints", json.dumps([endpoint]))
    c.insert_json5("scouting/multicast/enabled", "false")
    s = zenoh.open(c)

    def on_query(q: zenoh.Query) -> None:
        with q:
            body = json.loads(q.payload.to_bytes()) if q.payload is not None else None
            q.reply(q.key_expr, json.dumps({"received": body}))

    q = s.declare_queryable("hitch/goto", on_query)
    yield endpoint
    q.undeclare()
    s.close()


def test_numpy_values_are_sent_as_numbers_and_a_goal_must_be_a_mapping(echo):
    with HitchClient([echo], timeout_s=5.0) as c:
        got = c.goto({"z": np.float32(0.25), "x": np.float64(0.0)}, speed_scale=np.float32(0.5))["received"]
        assert got["goal"] == {"z": pytest.approx(0.25), "x": 0.0} and got["speed_scale"] == pytest.approx(0.5)
        with pytest.raises(ClientError, match=r"goal must be a mapping of x, z, roll, pitch .* got \[0\.1\]"):
            c.goto([0.1])  # type: ignore[arg-type]
        with pytest.raises(ClientError, match="goto: the payload cannot be sent as JSON .*a object is not a JSON"):
            c.goto({"z": object()})  # type: ignore[dict-item]
