"""Opening a bus: refusals name the interface, the channel and what to do."""

from __future__ import annotations

import pytest

from bridge.link.realtime import INTERFACES, open_bus
from bridge.link.state import LinkError
from tests.integration.service_process import free_port


def test_an_unknown_interface_names_the_allowed_ones():
    with pytest.raises(LinkError) as err:
        open_bus("pcan")  # refused by name before any bus is opened
    assert str(err.value) == f"interface must be one of {', '.join(INTERFACES)}, got 'pcan'"
    assert len(INTERFACES) == 4 and "socketcan" in INTERFACES and "remote" in INTERFACES


def test_a_remote_channel_without_a_hub_says_to_start_one():
    """A new user's report: `hitch switch raise` said only 'Connection refused'. And the hint said `hitch can-hub`
    (its default port 54701) for any port: a hub started so is not found; it names the port."""
    port = free_port()  # nothing listens there
    url = f"ws://127.0.0.1:{port}/"
    with pytest.raises(LinkError) as err:
        open_bus("remote", url)
    msg = str(err.value)
    assert url in msg and f"start one with `hitch can-hub --port {port}`" in msg
