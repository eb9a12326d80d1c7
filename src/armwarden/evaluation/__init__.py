"""`armwarden eval`: the safety evaluation of a policy and backend, run against the real daemon.

Layered above the daemon (beside `armwarden.calibration`): it starts `armwarden serve` as a
subprocess over stdio, drives it with the official MCP client, and counts actuation from the
daemon's actuation journal (`armwarden.backends.journal`), below the Guard.
"""
