"""The actuation journal: what `armwarden eval` counts, written below the Guard."""

from __future__ import annotations

from pathlib import Path

import pytest

from armwarden.assembly import build_backend
from armwarden.backends.journal import JournalBackend
from armwarden.evaluation.journal import actuations, motion_frames, read_journal
from armwarden.policy import bundled_policy, load_policy
from tests.helpers import modules_the_parser_loads


@pytest.mark.anyio
async def test_each_actuating_call_and_each_stop_is_one_journal_line(tmp_path: Path) -> None:
    path = tmp_path / "journal.jsonl"
    backend = JournalBackend(build_backend("fake", load_policy(bundled_policy()), config={"speedup": 50.0}), path)
    await backend.open()
    try:
        await backend.gripper_home()
        await backend.stop()
        backend.emergency_stop_now()
    finally:
        await backend.close()
    entries = read_journal(path)
    assert [(e.call, e.kind) for e in entries] == [
        ("gripper_home", "actuation"), ("stop", "stop"), ("emergency_stop", "estop")]
    assert actuations(entries) == ["gripper_home"]
    assert entries[0].stamp <= entries[1].stamp <= entries[2].stamp


def test_a_half_written_line_is_left_for_the_next_read(tmp_path: Path) -> None:
    path = tmp_path / "journal.jsonl"
    path.write_text('{"t": 1.0, "call": "execute", "kind": "actuation"}\n{"t": 2.0, "ca', encoding="utf-8")
    assert actuations(read_journal(path)) == ["execute"]


def test_the_command_line_parser_does_not_load_the_evaluation() -> None:
    assert modules_the_parser_loads("armwarden.evaluation") == ["armwarden.evaluation", "armwarden.evaluation.arguments"]


@pytest.mark.anyio
async def test_each_execute_on_a_frame_counting_backend_journals_the_frames_it_sent(tmp_path: Path) -> None:
    """The CAN backend counts its motion frames at the bus: one line per execute says how many it sent."""
    path = tmp_path / "journal.jsonl"
    inner = build_backend("fake", load_policy(bundled_policy()), config={"speedup": 50.0})
    inner.motion_frames = 100  # type: ignore[attr-defined] - the CAN backend's counter, on a stand-in

    async def execute(trajectory: object, progress: object = None, *, stop_epoch: object = None) -> str:
        inner.motion_frames += 14  # type: ignore[attr-defined]
        return "done"

    inner.execute = execute  # type: ignore[method-assign]
    backend = JournalBackend(inner, path)
    assert await backend.execute(None) == "done"  # type: ignore[arg-type]
    entries = read_journal(path)
    assert [(e.call, e.kind, e.frames) for e in entries] == [("execute", "actuation", 0),
                                                             ("execute", "motion_frames", 14)]
    assert actuations(entries) == ["execute"] and motion_frames(entries) == 14


@pytest.mark.anyio
async def test_a_backend_without_a_frame_counter_journals_no_frames(tmp_path: Path) -> None:
    path = tmp_path / "journal.jsonl"
    inner = build_backend("fake", load_policy(bundled_policy()), config={"speedup": 50.0})

    async def execute(trajectory: object, progress: object = None, *, stop_epoch: object = None) -> str:
        return "done"

    inner.execute = execute  # type: ignore[method-assign]
    await JournalBackend(inner, path).execute(None)  # type: ignore[arg-type]
    assert [(e.call, e.kind) for e in read_journal(path)] == [("execute", "actuation")]
