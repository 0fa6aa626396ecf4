"""Limits of the hitch and the tractor: workspaces, kinematic margins, stability of tractor + implement."""
