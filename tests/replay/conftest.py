"""One recorded session (tests/replay/session.py) shared by every replay test: recording it drives
a whole session through the MCP client, and the tests only read the log (or copy it to edit)."""

from __future__ import annotations

import anyio
import pytest

from tests.replay.session import SessionLog, record_session


@pytest.fixture(scope="session")
def session_log(tmp_path_factory: pytest.TempPathFactory) -> SessionLog:
    # A session-scoped fixture cannot be async under anyio's plugin (its event loop is per test),
    # so the recording runs in its own loop here.
    return anyio.run(record_session, tmp_path_factory.mktemp("replay-session"))
