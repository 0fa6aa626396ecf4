"""The ``hitch`` command line: every sub-command, arm included. Nothing outside ``bridge.cli`` imports it."""

from bridge.cli.main import build_parser, main

__all__ = ["build_parser", "main"]
