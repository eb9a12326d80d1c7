"""A person's go-ahead before a command moves a real arm outside the daemon's own approvals.

`calibrate-contact` and `armwarden eval` on a user's own cell drive the arm through plans that the
command approves itself. Before either starts, the person at the arm reads what will move and types
`yes`; `--yes` answers for simulation and CI. With neither (no terminal to ask on) nothing moves.
"""

from __future__ import annotations

from typing import TextIO

__all__ = ["confirmed"]


def confirmed(what_moves: str, *, assume_yes: bool, command: str, stdin: TextIO, stderr: TextIO) -> bool:
    """Print `what_moves` to `stderr`, then whether the person said `yes` (or `assume_yes`).

    Refusals say so on `stderr`, naming `command` and that nothing moved."""
    print(what_moves, file=stderr)
    if assume_yes:
        return True
    if not stdin.isatty():
        print(f"{command}: no terminal to ask on and no --yes: nothing moved", file=stderr)
        return False
    print("Type yes to start: ", end="", file=stderr, flush=True)
    try:
        answer = stdin.readline()
    except KeyboardInterrupt:
        answer = ""
    if answer.strip().lower() != "yes":
        print(f"{command}: not approved: nothing moved", file=stderr)
        return False
    return True
