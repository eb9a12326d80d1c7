"""`send_estop` and `armwarden estop`: a confirmed stop, or a clear failure."""

from __future__ import annotations

import argparse
import signal
import socket
from collections.abc import Iterator
from pathlib import Path

import pytest

from armwarden.stopchannel import (
    EStopRefused,
    EStopRequestError,
    EStopTimeout,
    EStopUnauthorized,
    EStopUnreachable,
    StopChannel,
    add_estop_arguments,
    estop_command,
    send_estop,
)
from armwarden.stopchannel import client as client_module

from .conftest import OPERATOR_TOKEN, Latch


def parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="armwarden estop")
    add_estop_arguments(parser)
    return parser.parse_args(argv)


@pytest.fixture
def token_file(tmp_path: Path) -> Path:
    path = tmp_path / "token"
    path.write_text(OPERATOR_TOKEN + "\n")
    return path


@pytest.fixture
def unused_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@pytest.fixture
def silent_server() -> Iterator[int]:
    """A port that accepts connections (in the backlog) but never answers."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        sock.listen(8)
        yield sock.getsockname()[1]


# ---------------------------------------------------------------------------------------------- send_estop
def test_send_estop_returns_the_confirmed_event(channel: StopChannel, latch: Latch) -> None:
    answer = send_estop(channel.url, OPERATOR_TOKEN, "from a script")

    assert answer["estopped"] is True and answer["event"] == 1
    assert latch.calls == [("from a script", "alice")]


def test_send_estop_accepts_a_url_without_the_path(channel: StopChannel, latch: Latch) -> None:
    send_estop(f"http://127.0.0.1:{channel.port}", OPERATOR_TOKEN)

    assert latch.calls == [("", "alice")]


def test_send_estop_raises_on_a_refused_token(channel: StopChannel) -> None:
    with pytest.raises(EStopUnauthorized, match="unknown bearer token"):
        send_estop(channel.url, "aw_wrong")


def test_send_estop_raises_when_nothing_listens(unused_port: int) -> None:
    with pytest.raises(EStopUnreachable):
        send_estop(f"http://127.0.0.1:{unused_port}/estop", OPERATOR_TOKEN)


def test_send_estop_raises_when_the_channel_does_not_answer(silent_server: int) -> None:
    with pytest.raises(EStopTimeout):
        send_estop(f"http://127.0.0.1:{silent_server}/estop", OPERATOR_TOKEN, timeout_s=0.2)


def test_send_estop_raises_when_the_stop_failed(make_channel) -> None:
    def failing_latch(reason: str, principal: str) -> int:
        raise RuntimeError("stop command lost")

    channel = make_channel(latch_and_stop=failing_latch)
    with pytest.raises(EStopRefused, match="stop command lost") as refused:
        send_estop(channel.url, OPERATOR_TOKEN)

    assert refused.value.status == 500


@pytest.mark.parametrize("url", ["https://127.0.0.1:1/estop", "127.0.0.1:1", "http://127.0.0.1:notaport/"])
def test_send_estop_refuses_a_url_it_cannot_use(url: str) -> None:
    with pytest.raises(EStopRequestError):
        send_estop(url, OPERATOR_TOKEN)


# ---------------------------------------------------------------------------------------------- armwarden estop
def test_the_command_stops_through_the_channel(channel: StopChannel, latch: Latch, token_file: Path, capsys) -> None:
    code = estop_command(parse(["--url", channel.url, "--token-file", str(token_file), "--reason", "button"]))

    assert code == 0
    assert "event 1" in capsys.readouterr().out
    assert latch.calls == [("button", "alice")]


def test_the_command_reports_a_refused_token_on_one_line(channel: StopChannel, tmp_path: Path, capsys) -> None:
    wrong = tmp_path / "wrong"
    wrong.write_text("aw_wrong")

    code = estop_command(parse(["--url", channel.url, "--token-file", str(wrong)]))

    err = capsys.readouterr().err
    assert code == 1
    assert "refused the token" in err and err.count("\n") == 1


def test_the_command_needs_a_token_file_with_a_url(channel: StopChannel, latch: Latch, capsys) -> None:
    assert estop_command(parse(["--url", channel.url])) == 1
    assert "--token-file" in capsys.readouterr().err
    assert latch.calls == []


def test_the_command_reports_an_unreadable_token_file(channel: StopChannel, tmp_path: Path, capsys) -> None:
    assert estop_command(parse(["--url", channel.url, "--token-file", str(tmp_path / "missing")])) == 1
    assert "cannot read token file" in capsys.readouterr().err


def test_the_command_reports_an_unreachable_channel(unused_port: int, token_file: Path, capsys) -> None:
    code = estop_command(parse(["--url", f"http://127.0.0.1:{unused_port}/estop", "--token-file", str(token_file)]))

    assert code == 1
    assert "FAILED" in capsys.readouterr().err


def test_the_command_signals_a_pid_with_sigusr1(monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    sent: list[tuple[int, int]] = []
    monkeypatch.setattr(client_module.os, "kill", lambda pid, sig: sent.append((pid, sig)))

    assert estop_command(parse(["--pid", "4242"])) == 0
    assert sent == [(4242, signal.SIGUSR1)]


def test_the_command_reports_a_missing_process(monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    def no_such_process(pid: int, sig: int) -> None:
        raise ProcessLookupError

    monkeypatch.setattr(client_module.os, "kill", no_such_process)

    assert estop_command(parse(["--pid", "4242"])) == 1
    assert "no process 4242" in capsys.readouterr().err


@pytest.mark.parametrize("pid", ["0", "-1"])
def test_the_command_never_signals_a_process_group(monkeypatch: pytest.MonkeyPatch, pid: str, capsys) -> None:
    sent: list[tuple[int, int]] = []
    monkeypatch.setattr(client_module.os, "kill", lambda pid, sig: sent.append((pid, sig)))

    assert estop_command(parse(["--pid", pid])) == 1
    assert sent == []
    assert "positive process id" in capsys.readouterr().err


def test_url_and_pid_are_mutually_exclusive() -> None:
    with pytest.raises(SystemExit):
        parse(["--url", "http://127.0.0.1:1/estop", "--pid", "1"])
