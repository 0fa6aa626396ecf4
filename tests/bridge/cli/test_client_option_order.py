"""Client options (``--connect``, ``--timeout``, ``--json`` …) stand before or after a group's action.

Before, ``hitch faults --connect X list`` was refused ("argument action: invalid choice: 'X'") and, on a group that
took the option, its action's argparse default overrode the value given before it.
"""

from __future__ import annotations

import pytest

from bridge.cli.errors import CLIError
from bridge.cli.main import build_parser

ENDPOINT = "tcp/127.0.0.1:47991"

#: (group words, action words) of every client command group
GROUPS = [
    (["faults"], ["list"]),
    (["faults"], ["ack"]),
    (["preset"], ["list"]),
    (["preset"], ["go", "headland"]),
    (["maneuver"], ["list"]),
    (["maneuver"], ["run", "turn"]),
    (["maneuver", "record"], ["start"]),
    (["fleet"], ["ls"]),
    (["implement"], ["list"]),
    (["implement"], ["select", "plough"]),
    (["work"], ["settings"]),
    (["lines"], ["list"]),
]
OPTIONS = ["--connect", ENDPOINT, "--prefix", "fleet/t07/hitch", "--timeout", "2.5", "--json", "--user", "alice"]
CLIENT_DESTS = ("connect", "prefix", "timeout", "json", "user", "security", "realtime")


def _client_view(argv: list[str]) -> dict:
    args = build_parser().parse_args(argv)
    return {d: getattr(args, d) for d in CLIENT_DESTS}


@pytest.mark.parametrize(("group", "action"), GROUPS, ids=lambda v: " ".join(v))
def test_client_options_before_the_action_mean_what_they_mean_after_it(group, action):
    after = _client_view([*group, *action, *OPTIONS])
    before = _client_view([*group, *OPTIONS, *action])
    assert before == after
    assert after["connect"] == [ENDPOINT] and after["timeout"] == 2.5 and after["json"] is True
    assert after["prefix"] == "fleet/t07/hitch" and after["user"] == "alice"


@pytest.mark.parametrize(("group", "action"), GROUPS, ids=lambda v: " ".join(v))
def test_without_client_options_every_command_gets_their_defaults(group, action):
    view = _client_view([*group, *action])
    fleet = group == ["fleet"]
    assert view == {
        "connect": None,
        "prefix": None if fleet else "hitch",  # fleet ls: a filter, none by default
        "timeout": 5.0,
        "json": False,
        "user": None,
        "security": None,
        "realtime": False,
    }


def test_given_at_both_levels_the_actions_value_wins_and_the_defaults_are_not_shared():
    view = _client_view(["faults", "--timeout", "3", "--connect", "tcp/127.0.0.1:1", "list", "--timeout", "4"])
    assert view["timeout"] == 4.0 and view["connect"] == ["tcp/127.0.0.1:1"]
    # endpoints at both levels are all taken (a review: the group's were dropped silently)
    view = _client_view(["faults", "--connect", "tcp/a:1", "list", "--connect", "tcp/b:2", "--connect", "tcp/c:3"])
    assert view["connect"] == ["tcp/a:1", "tcp/b:2", "tcp/c:3"]
    assert not hasattr(build_parser().parse_args(["faults", "--connect", "tcp/a:1", "list"]), "outer_connect")
    # an appended --connect starts from a fresh list each time (the default is not a shared object)
    a = build_parser().parse_args(["faults", "list"])
    assert a.connect is None
    b = build_parser().parse_args(["state", "--connect", "tcp/127.0.0.1:2"])
    assert b.connect == ["tcp/127.0.0.1:2"]


def test_a_bad_value_before_the_action_names_the_option_and_its_range():
    with pytest.raises(CLIError, match=r"--timeout.*\(0, 600\]"):
        build_parser().parse_args(["faults", "--timeout", "0", "list"])


def test_single_level_client_commands_keep_their_options():
    view = _client_view(["state", "--connect", ENDPOINT, "--timeout", "1"])
    assert view["connect"] == [ENDPOINT] and view["timeout"] == 1.0 and view["prefix"] == "hitch"
