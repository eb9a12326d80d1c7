"""The independent stop channel: an e-stop path beside MCP that no command load can delay.

`StopChannel` serves ``POST /estop`` (and, with a `ConsoleDoor`, the operator console's
``POST /console-estop``) on its own thread and socket; `send_estop` and
`estop_command` are the client side (``armwarden estop``).
"""

from armwarden.stopchannel.client import (
    EStopRefused,
    EStopRequestError,
    EStopTimeout,
    EStopUnauthorized,
    EStopUnreachable,
    add_estop_arguments,
    estop_command,
    send_estop,
)
from armwarden.stopchannel.console_door import ConsoleDoor
from armwarden.stopchannel.records import ChannelRefusal, ChannelStop
from armwarden.stopchannel.server import StopChannel, token_store_authenticator

__all__ = [
    "ChannelRefusal",
    "ChannelStop",
    "ConsoleDoor",
    "EStopRefused",
    "EStopRequestError",
    "EStopTimeout",
    "EStopUnauthorized",
    "EStopUnreachable",
    "StopChannel",
    "add_estop_arguments",
    "estop_command",
    "send_estop",
    "token_store_authenticator",
]
