"""`armwarden estop --pid P --reason R`: the reason reaches the audit record of the SIGUSR1 stop
(issue 31, item 7: it said "SIGUSR1 received"), through an owner-only file the daemon reads only
after the stop is issued, and never trusts for anything but its text."""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from armwarden.stopchannel import add_estop_arguments, estop_command, reasons
from armwarden.stopchannel import client as client_module
from armwarden.stopchannel import signals as signals_module
from armwarden.stopchannel.reasons import MAX_REASON_BYTES, discard_reasons, take_reasons, write_reason
from armwarden.stopchannel.signals import SIGNAL_PRINCIPAL, SignalStop
from armwarden.stopchannel.wire import REASON_LIMIT
from tests.helpers import CLI, REPO, child_env, records_of
from tests.server.http_daemon import http_daemon

from .conftest import Events, Latch

PID = 4242


def parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="armwarden estop")
    add_estop_arguments(parser)
    return parser.parse_args(argv)


@pytest.fixture
def directory(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The reason directory of this test (the command's and the reader's default points there)."""
    path = tmp_path / "reasons"
    monkeypatch.setattr(reasons, "reason_directories", lambda: [path])
    return path


def wait_for(predicate, timeout_s: float = 30.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, "condition not reached in time"
        time.sleep(0.05)


# ------------------------------------------------------------------------------------ the files
def test_a_written_reason_is_taken_once_and_removed(directory: Path) -> None:
    path = write_reason(PID, "hand on the button")
    assert oct(path.stat().st_mode & 0o777) == oct(0o600) and oct(directory.stat().st_mode & 0o777) == oct(0o700)
    assert take_reasons(PID) == "hand on the button"
    assert list(directory.iterdir()) == []
    assert take_reasons(PID) is None


def test_only_the_reasons_for_this_process_id_are_taken(directory: Path) -> None:
    write_reason(PID + 1, "for another daemon")
    write_reason(PID, "first")
    write_reason(PID, "second")
    assert take_reasons(PID) == "first; second"
    assert take_reasons(PID + 1) == "for another daemon"


def test_a_reason_is_cleaned_to_one_bounded_line(directory: Path) -> None:
    write_reason(PID, "line one\nline two\x1b[31m" + "x" * 1000)
    text = take_reasons(PID)
    assert text is not None and text.startswith("line one line two[31m") and "\n" not in text and "\x1b" not in text
    assert len(text) <= REASON_LIMIT


def test_a_reason_file_others_may_read_or_write_is_refused_and_removed(directory: Path) -> None:
    write_reason(PID, "trusted").chmod(0o666)
    assert take_reasons(PID) is None
    assert list(directory.iterdir()) == []


def test_a_symbolic_link_is_never_followed(directory: Path, tmp_path: Path) -> None:
    target = tmp_path / "secret"
    target.write_text("do not read me", encoding="utf-8")
    target.chmod(0o600)
    write_reason(PID, "placeholder")  # creates the directory
    take_reasons(PID)
    (directory / f"estop-{PID}-1-link.reason").symlink_to(target)
    assert take_reasons(PID) is None
    assert target.read_text(encoding="utf-8") == "do not read me"


def test_a_fifo_named_as_a_reason_does_not_block_the_reader(directory: Path) -> None:
    write_reason(PID, "placeholder")
    take_reasons(PID)
    os.mkfifo(directory / f"estop-{PID}-1-fifo.reason", 0o600)  # nobody ever writes to it
    assert take_reasons(PID) is None


def test_a_reason_file_over_the_size_limit_is_refused_unread(directory: Path) -> None:
    path = write_reason(PID, "placeholder")
    path.write_bytes(b"x" * (MAX_REASON_BYTES + 1))
    assert take_reasons(PID) is None


def test_a_stale_reason_is_not_taken(directory: Path) -> None:
    path = write_reason(PID, "for a stop never sent")
    long_ago = time.time() - reasons.MAX_REASON_AGE_S - 60
    os.utime(path, (long_ago, long_ago))
    assert take_reasons(PID) is None


def test_a_directory_others_may_use_is_not_read_and_not_written(directory: Path) -> None:
    directory.mkdir(mode=0o700)
    (directory / f"estop-{PID}-1-x.reason").write_text("planted", encoding="utf-8")
    directory.chmod(0o777)
    assert take_reasons(PID) is None
    with pytest.raises(PermissionError):
        write_reason(PID, "mine")


def test_a_stop_takes_only_the_reasons_signalled_between_its_wake_and_the_last(directory: Path) -> None:
    write_reason(PID, "came after its own stop was recorded", signalled_ns=100)
    write_reason(PID, "this stop's", signalled_ns=200)
    write_reason(PID, "the next stop's", signalled_ns=300)
    assert take_reasons(PID, signalled_from_ns=150, signalled_before_ns=300) == "this stop's"
    assert take_reasons(PID) == "the next stop's"
    assert list(directory.iterdir()) == []


def test_reasons_left_for_this_process_id_are_discarded(directory: Path) -> None:
    write_reason(PID, "left by an earlier process with this id")
    discard_reasons(PID)
    assert take_reasons(PID) is None


# -------------------------------------------------------------------------------- the directory
@pytest.fixture
def places(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> dict[str, Path]:
    """This test's stand-ins for $XDG_RUNTIME_DIR, /run/user and /tmp (none of them created)."""
    found = {"xdg": tmp_path / "xdg", "run_user": tmp_path / "run" / "user", "tmp": tmp_path / "tmp"}
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(found["xdg"]))
    monkeypatch.setattr(reasons, "RUNTIME_ROOT", found["run_user"])
    monkeypatch.setattr(reasons, "SHARED_TMP", found["tmp"])
    found["tmp"].mkdir(mode=0o777)
    return found


def test_reasons_go_to_the_users_runtime_directory(places: dict[str, Path]) -> None:
    places["xdg"].mkdir(mode=0o700)
    assert reasons.reason_directory() == places["xdg"] / "armwarden"


def test_without_xdg_runtime_dir_reasons_go_to_run_user_when_it_is_ours(
        places: dict[str, Path], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("XDG_RUNTIME_DIR")
    (places["run_user"] / str(os.geteuid())).mkdir(mode=0o700, parents=True)
    assert reasons.reason_directory() == places["run_user"] / str(os.geteuid()) / "armwarden"


def test_a_runtime_directory_others_may_use_is_passed_over_for_the_shared_one(places: dict[str, Path]) -> None:
    places["xdg"].mkdir(mode=0o700)
    places["xdg"].chmod(0o777)
    assert reasons.reason_directory() == places["tmp"] / f"armwarden-{os.geteuid()}"


def test_a_squatted_shared_directory_does_not_lose_the_reason_given_a_runtime_directory(
        places: dict[str, Path], monkeypatch: pytest.MonkeyPatch) -> None:
    squatted = places["tmp"] / f"armwarden-{os.geteuid()}"
    squatted.mkdir(mode=0o700)
    squatted.chmod(0o777)  # what another user's directory looks like to the checks: not ours alone
    places["xdg"].mkdir(mode=0o700)
    monkeypatch.setattr(os, "kill", lambda pid, sig: None)
    assert estop_command(parse(["--pid", str(PID), "--reason", "hand on the button"])) == 0
    assert take_reasons(PID) == "hand on the button"


def test_the_daemon_finds_a_reason_in_any_of_the_users_directories(places: dict[str, Path]) -> None:
    """The command and the daemon may not share $XDG_RUNTIME_DIR (a service started without it)."""
    places["xdg"].mkdir(mode=0o700)
    write_reason(PID, "from a shell without XDG_RUNTIME_DIR", places["tmp"] / f"armwarden-{os.geteuid()}")
    assert take_reasons(PID) == "from a shell without XDG_RUNTIME_DIR"


def test_the_command_says_which_directory_it_refused(places: dict[str, Path], monkeypatch: pytest.MonkeyPatch,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.delenv("XDG_RUNTIME_DIR")
    squatted = places["tmp"] / f"armwarden-{os.geteuid()}"
    squatted.mkdir(mode=0o700)
    squatted.chmod(0o755)
    sent: list[int] = []
    monkeypatch.setattr(os, "kill", lambda pid, sig: sent.append(pid))
    assert estop_command(parse(["--pid", str(PID), "--reason", "hand on the button"])) == 0
    err = capsys.readouterr().err
    assert sent == [PID] and f"reason directory {squatted} refused" in err and "XDG_RUNTIME_DIR" in err


# ------------------------------------------------------------------------------- the signal side
def test_the_stop_is_issued_before_the_reason_is_read_and_the_record_carries_it(
        directory: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    order: list[str] = []
    latch, events = Latch(), Events()

    def latch_and_stop(reason: str, principal: str) -> int:
        order.append("stop")
        return latch(reason, principal)

    def take(*args: Any, **kwargs: Any) -> str | None:
        order.append("reason")
        return take_reasons(*args, **kwargs)

    monkeypatch.setattr(signals_module, "take_reasons", take)
    with SignalStop(latch_and_stop, on_event=events, reason_directory=directory):
        write_reason(os.getpid(), "hand on the button")
        os.kill(os.getpid(), signal.SIGUSR1)
        assert events.arrived.wait(30.0)
    assert order == ["stop", "reason"]
    assert latch.calls == [("SIGUSR1 received", SIGNAL_PRINCIPAL)]  # the stop never depends on the reason
    (stop,) = events.received
    assert stop.reason == "hand on the button" and stop.event == 1 and stop.error is None


def test_a_reason_written_during_an_earlier_stop_is_not_put_on_it(directory: Path) -> None:
    """A wired button's bare ``kill -USR1`` is still being issued when an operator's command
    hands over its reason and signals: the reason is the second stop's, not the first's."""
    in_first_stop, finish_first_stop = threading.Event(), threading.Event()
    events, latch = Events(), Latch()

    def latch_and_stop(reason: str, principal: str) -> int:
        number = latch(reason, principal)
        if number == 1:  # the first stop takes a moment (the backend's stop_now)
            in_first_stop.set()
            assert finish_first_stop.wait(30.0)
        return number

    with SignalStop(latch_and_stop, on_event=events, reason_directory=directory):
        os.kill(os.getpid(), signal.SIGUSR1)  # stop 1: no reason
        assert in_first_stop.wait(30.0)
        write_reason(os.getpid(), "operator: gripper dropped the part", directory)
        os.kill(os.getpid(), signal.SIGUSR1)  # stop 2
        finish_first_stop.set()
        wait_for(lambda: len(events.received) == 2)
    assert [(stop.event, stop.reason) for stop in events.received] == [
        (1, "SIGUSR1 received"), (2, "operator: gripper dropped the part")]


def test_a_reason_handed_over_after_the_stop_reaches_its_record_and_not_a_later_ones(
        directory: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The command signals first and writes after: stop 1's reason arrives while its record
    waits, after stop 2's command (signalled during stop 1) has written its own."""
    in_first_stop, finish_first_stop, polled = threading.Event(), threading.Event(), threading.Event()
    events, latch = Events(), Latch()

    def latch_and_stop(reason: str, principal: str) -> int:
        number = latch(reason, principal)
        if number == 1:
            in_first_stop.set()
            assert finish_first_stop.wait(30.0)
        return number

    def take(*args: Any, **kwargs: Any) -> str | None:
        text = take_reasons(*args, **kwargs)
        polled.set()
        return text

    monkeypatch.setattr(signals_module, "take_reasons", take)
    with SignalStop(latch_and_stop, on_event=events, reason_directory=directory, reason_grace_s=30.0):
        first_signalled = time.monotonic_ns()
        os.kill(os.getpid(), signal.SIGUSR1)  # command 1 signals...
        assert in_first_stop.wait(30.0)
        second_signalled = time.monotonic_ns()  # command 2, during stop 1: signal, then its reason
        os.kill(os.getpid(), signal.SIGUSR1)
        write_reason(os.getpid(), "second", directory, signalled_ns=second_signalled)
        finish_first_stop.set()
        assert polled.wait(30.0)  # stop 1's record has looked once and found nothing of its own
        write_reason(os.getpid(), "first", directory, signalled_ns=first_signalled)  # ...and writes late
        wait_for(lambda: len(events.received) == 2)
    assert [(stop.event, stop.reason) for stop in events.received] == [(1, "first"), (2, "second")]


def test_waiting_for_a_reason_never_holds_back_the_next_stop(directory: Path) -> None:
    events, latch = Events(), Latch()
    with SignalStop(latch, on_event=events, reason_directory=directory, reason_grace_s=60.0):
        os.kill(os.getpid(), signal.SIGUSR1)
        wait_for(lambda: len(latch.calls) == 1)
        os.kill(os.getpid(), signal.SIGUSR1)
        wait_for(lambda: len(latch.calls) == 2)  # issued while stop 1's record still waits for a reason
        assert events.received == []
    assert [(stop.event, stop.reason) for stop in events.received] == [(1, "SIGUSR1 received"), (2, "SIGUSR1 received")]


def test_a_signal_without_a_reason_is_recorded_as_received(directory: Path) -> None:
    events = Events()
    with SignalStop(Latch(), on_event=events, reason_directory=directory):
        os.kill(os.getpid(), signal.SIGUSR1)
        assert events.arrived.wait(30.0)
    assert events.received[0].reason == "SIGUSR1 received"


# ------------------------------------------------------------------------------- the command side
def test_the_command_signals_before_it_writes_the_reason(directory: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A stalled file system must not hold the stop back: the signal goes first."""
    order: list[str] = []
    signalled_ns: list[int] = []

    def kill(pid: int, sig: int) -> None:
        order.append("signal")
        signalled_ns.append(time.monotonic_ns())

    def write(*args: Any, **kwargs: Any) -> Path:
        order.append("reason")
        return write_reason(*args, **kwargs)

    monkeypatch.setattr(os, "kill", kill)
    monkeypatch.setattr(client_module, "write_reason", write)
    assert estop_command(parse(["--pid", str(PID), "--reason", "hand on the button"])) == 0
    assert order == ["signal", "reason"]
    # the file names a time taken before the signal: the stop that answers it woke after
    assert take_reasons(PID, signalled_before_ns=signalled_ns[0] + 1) == "hand on the button"


def test_the_command_signals_even_when_the_reason_cannot_be_written(
        directory: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    directory.mkdir(mode=0o755)  # not private: the reason is refused
    sent: list[tuple[int, int]] = []
    monkeypatch.setattr(os, "kill", lambda pid, sig: sent.append((pid, sig)))
    assert estop_command(parse(["--pid", str(PID), "--reason", "hand on the button"])) == 0
    assert sent == [(PID, signal.SIGUSR1)]
    assert "the e-stop was sent without it" in capsys.readouterr().err


def test_the_command_does_not_wait_for_a_hung_reason_write(directory: Path, monkeypatch: pytest.MonkeyPatch,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    release = threading.Event()
    monkeypatch.setattr(client_module, "write_reason", lambda *args, **kwargs: release.wait(60.0))
    monkeypatch.setattr(client_module, "REASON_WRITE_BUDGET_S", 0.05)
    sent: list[int] = []
    monkeypatch.setattr(os, "kill", lambda pid, sig: sent.append(pid))
    try:
        assert estop_command(parse(["--pid", str(PID), "--reason", "hand on the button"])) == 0
        assert not release.is_set() and sent == [PID]  # returned, signalled, while the write still hangs
        assert "not written within 0.05 s" in capsys.readouterr().err  # the budget the test set
    finally:
        release.set()


def test_no_reason_is_left_for_a_process_that_does_not_exist(directory: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def no_such_process(pid: int, sig: int) -> None:
        raise ProcessLookupError

    monkeypatch.setattr(os, "kill", no_such_process)
    assert estop_command(parse(["--pid", str(PID), "--reason", "too late"])) == 1
    assert not directory.exists() or list(directory.iterdir()) == []


# ------------------------------------------------------------------------------------ end to end
def test_the_reason_of_estop_by_pid_reaches_the_audit_record(tmp_path: Path) -> None:
    with http_daemon(tmp_path, speedup=0.5) as daemon:
        # held while the command signals and writes, the daemon finds the reason however loaded
        # the machine is (the record's wait for a late reason is tested above)
        daemon.process.send_signal(signal.SIGSTOP)
        try:
            result = subprocess.run([*CLI, "estop", "--pid", str(daemon.process.pid), "--reason", "hand on the button"],
                                    cwd=REPO, env=child_env(), capture_output=True, text=True, timeout=60)
        finally:
            daemon.process.send_signal(signal.SIGCONT)
        assert result.returncode == 0, result.stderr

        def signal_stops() -> list[dict]:
            return [r for r in records_of(daemon.audit) if r["event"] == "estop" and r["principal"] == SIGNAL_PRINCIPAL]

        wait_for(lambda: len(signal_stops()) == 1)
        record = signal_stops()[0]
    assert record["outcome"] == "latched" and record["arguments"] == {"reason": "hand on the button"}
