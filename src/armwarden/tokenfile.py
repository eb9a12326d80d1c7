"""A bearer token read from a file, for the command-line clients (`armwarden estop --url`,
`armwarden snapshot`): a token never goes on a command line, where `ps` shows it to every user."""

from __future__ import annotations

from pathlib import Path

__all__ = ["read_token_file"]


def read_token_file(path: str) -> str:
    """The token `path` holds (surrounding whitespace dropped); `ValueError` naming the file when it
    cannot be read or holds anything but one token."""
    try:
        token = Path(path).read_text(encoding="utf-8").strip()
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"cannot read token file {path}: {exc}") from exc
    if not token or any(char.isspace() for char in token):
        raise ValueError(f"token file {path} must hold just the token")
    return token
