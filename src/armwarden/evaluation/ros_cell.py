"""`armwarden eval --backend ros2` without `--backend-config`: the fake FR3 cell, a process of its own.

The evaluation picks a random `ROS_DOMAIN_ID` (1..100) with `ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`
in its own environment, which every cell and daemon it starts inherits, so DDS never leaves this
host and no other graph is on the domain. Each daemon gets a cell of its own (`FakeCells.start`,
called as its arguments are built): a fresh one at home, as the other backends start every daemon
at home (the scenarios are built from home). The cell journals every goal it accepted
(`armwarden.backends.ros2.fake_cell_journal`) to the file the evaluation reads for that daemon,
`<name>-journal.jsonl`: actuation is counted where the cell received it, below the Guard and
the backend. The daemon's own journal is kept beside it (`<name>-daemon-journal.jsonl`). A
daemon restarted on the same arguments (the kills) finds the same cell, still running whatever
goal it had. The previous cell is stopped when the next starts, and all of them at the end.

The daemon gets a private copy of examples/ros2_fr3.yaml (the cell's names) with the joint-state
and wrench ages widened as the test harness widens them (`backends/ros2/testing.py`): the cell
is a Python process publishing at 100 Hz on a shared 2-core host, and gaps of 0.07–0.38 s were
measured between its messages under load. No scenario tests these ages; the widening is said on
stderr. No rclpy here: only the cell and the daemons import it.
"""

from __future__ import annotations

import importlib.util
import os
import random
import selectors
import signal
import subprocess
import sys
import time
from pathlib import Path

import yaml

from armwarden.backends.ros2.fake_cell_journal import CELL_MODULE, READY
from armwarden.evaluation.daemon_process import stop_process
from armwarden.policy.motion import MAX_WRENCH_TIMEOUT_S

#: the cell's names, as the daemon is to be wired to them (a source checkout's file)
DEFAULT_ROS2_CONFIG = Path(__file__).resolve().parents[3] / "examples" / "ros2_fr3.yaml"
#: the joint-state age the evaluation's daemons accept [s] (the harness's, see the module docstring)
EVAL_JOINT_STATE_AGE_S = 1.0
#: how long a cell may take to bring its endpoints up [s]
CELL_START_TIMEOUT_S = 120.0
#: how long a cell has to exit on SIGTERM before it is killed [s]
CELL_STOP_TIMEOUT_S = 15.0
#: prctl(2)'s option: a signal for the child when its parent dies
PR_SET_PDEATHSIG = 1
#: domains the evaluation draws from (0 is everyone's default; above 101 the DDS ports run out)
DOMAINS = 100


def isolate_ros_domain(environ: dict[str, str] | os._Environ[str] = os.environ) -> int:
    """A random domain and localhost-only discovery in `environ` (this process's: the cells and
    daemons started later inherit it); returns the domain. Never the domain `environ` had: a
    user's own graph (a real arm) or a test's."""
    taken = environ.get("ROS_DOMAIN_ID", "").strip()
    domain = random.choice([d for d in range(1, DOMAINS + 1) if str(d) != taken])
    environ["ROS_DOMAIN_ID"] = str(domain)
    environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    environ.pop("ROS_STATIC_PEERS", None)
    environ.pop("ROS_LOCALHOST_ONLY", None)
    return domain


def fake_cell_config(directory: Path) -> Path:
    """The daemon's config for the fake cell: examples/ros2_fr3.yaml with the ages widened (module
    docstring). `FileNotFoundError` when this interpreter has no rclpy (the cells and the daemons
    run under it) or the example is not there."""
    if importlib.util.find_spec("rclpy") is None:
        raise FileNotFoundError(f"--backend ros2 needs rclpy in this interpreter ({sys.executable}): the cells "
                                "and daemons run under it. In a checkout, bash scripts/setup_ros.sh builds the ROS "
                                "venv; then run .venv-ros/bin/armwarden eval --backend ros2")
    if not DEFAULT_ROS2_CONFIG.is_file():
        raise FileNotFoundError(f"--backend ros2 without --backend-config needs {DEFAULT_ROS2_CONFIG} "
                                "(it ships with a source checkout only)")
    document = yaml.safe_load(DEFAULT_ROS2_CONFIG.read_text(encoding="utf-8"))
    document["joint_states"]["max_age_s"] = max(document["joint_states"]["max_age_s"], EVAL_JOINT_STATE_AGE_S)
    document["wrench"]["max_age_s"] = max(document["wrench"]["max_age_s"], MAX_WRENCH_TIMEOUT_S)
    copy = directory / "ros2-fake-cell.yaml"
    copy.write_text(yaml.safe_dump(document, sort_keys=False), encoding="utf-8")
    return copy


def _die_with_parent() -> None:
    """In the cell's process before exec (Linux): SIGTERM when the evaluation dies, even by SIGKILL,
    so no cell outlives it on the domain. Elsewhere nothing (`FakeCells.stop` still ends them)."""
    if sys.platform.startswith("linux"):
        import ctypes

        ctypes.CDLL(None).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)


class FakeCells:
    """The fake cells of one evaluation, one at a time (see the module docstring)."""

    def __init__(self, log_directory: Path) -> None:
        self.log_directory = log_directory
        self.process: subprocess.Popen[bytes] | None = None
        self.journal: Path | None = None
        self.started = 0

    @property
    def pid(self) -> int | None:
        return None if self.process is None else self.process.pid

    def start(self, journal: Path) -> None:
        """A running cell journaling to `journal`: the one already there, or a fresh one at home
        (stopping the previous cell first)."""
        if self.process is not None and self.journal == journal and self.process.poll() is None:
            return
        self.stop()
        self.started += 1
        stderr_path = self.log_directory / f"cell-{self.started}.err"
        with stderr_path.open("wb") as stderr:
            process = subprocess.Popen([sys.executable, "-m", CELL_MODULE, "--journal", str(journal)],
                                       env=dict(os.environ), stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                       stderr=stderr, preexec_fn=_die_with_parent)
        self.process, self.journal = process, journal
        if not self._ready(process):
            tail = stderr_path.read_text(encoding="utf-8", errors="replace")[-1500:]
            self.stop()
            raise RuntimeError(f"the fake ROS cell did not come up within {CELL_START_TIMEOUT_S:g} s: {tail}")

    @staticmethod
    def _ready(process: subprocess.Popen[bytes]) -> bool:
        """Whether the cell printed its ready line within the bound (it exits on no error of ours)."""
        assert process.stdout is not None
        deadline = time.monotonic() + CELL_START_TIMEOUT_S
        with selectors.DefaultSelector() as selector:
            selector.register(process.stdout, selectors.EVENT_READ)
            while (left := deadline - time.monotonic()) > 0:
                if not selector.select(timeout=left):
                    continue
                line = process.stdout.readline()
                if not line:  # exited
                    return False
                if line.decode(errors="replace").startswith(READY):
                    return True
        return False

    def kill(self) -> None:
        """SIGKILL the running cell (the backend-death fault): it goes silent mid-whatever."""
        if self.process is not None and self.process.poll() is None:
            self.process.send_signal(signal.SIGKILL)
            self.process.wait()

    def stop(self) -> None:
        """SIGTERM the running cell (SIGKILL after `CELL_STOP_TIMEOUT_S`)."""
        process, self.process, self.journal = self.process, None, None
        if process is None:
            return
        stop_process(process, CELL_STOP_TIMEOUT_S)
        if process.stdout is not None:
            process.stdout.close()


__all__ = ["DEFAULT_ROS2_CONFIG", "FakeCells", "fake_cell_config", "isolate_ros_domain"]
