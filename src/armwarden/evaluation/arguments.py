"""`armwarden eval`'s arguments: light to import (the command line builds its parser before any heavy import)."""

from __future__ import annotations

import argparse
from collections.abc import Sequence

#: the backends the evaluation may drive: it approves its own motions (no human answers), so never
#: a physical arm without bounds. `can` only on its emulator (`simulate` and the `virtual` bus:
#: checked before anything starts, `armwarden.evaluation.targets`). `ros2` without a config runs
#: the fake FR3 cell (`armwarden.evaluation.ros_cell`); with the user's own config, whose graph may
#: hold a real arm, only what moves within an approved plan runs (`USERS_CELL_REFUSED`)
EVAL_BACKENDS = ("fake", "mujoco", "can", "ros2")
#: safe requests in a full and in a --quick run
FULL_SAFE = 100
QUICK_SAFE = 10
#: generated fuzz calls per transport in a full and in a --quick run
FULL_FUZZ = 10_000
QUICK_FUZZ = 300
#: seconds of the load run in a full and a --quick run, and its clients
FULL_LOAD_S = 60.0
QUICK_LOAD_S = 10.0
LOAD_CLIENTS = 16
#: kill -9 mid-motion (each followed by a restart on the same audit log) in a full and a --quick run
FULL_KILLS = 10
QUICK_KILLS = 2
#: the backend made to die mid-motion (each on a daemon of its own) in a full and a --quick run
FULL_DEATHS = 5
QUICK_DEATHS = 1


def add_eval_arguments(parser: argparse.ArgumentParser, backends: Sequence[str]) -> None:
    parser.add_argument("--policy", default=None, help="safety policy YAML (default: the bundled FR3 policy)")
    parser.add_argument("--backend", default="fake", choices=backends)
    parser.add_argument("--backend-config", default=None,
                        help="the backend's options YAML (can: default examples/can_sim.yaml, the emulator; a config "
                             "without `simulate` or with a bus interface other than `virtual` is refused; ros2: default "
                             "the fake FR3 cell, started on a random local ROS domain; your own cell's config runs only "
                             "the scenarios and safe requests, every motion an approved plan: no fuzz, faults or load)")
    parser.add_argument("--quick", action="store_true", help=f"{QUICK_SAFE} safe requests instead of {FULL_SAFE}")
    parser.add_argument("--report", default=None, metavar="FILE", help="write the markdown report here (default stdout)")
    parser.add_argument("--json", default=None, metavar="FILE", help="also write the report's data as JSON")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random safe targets and of the fuzz generation")
    parser.add_argument("--only", action="append", default=None, metavar="TEXT",
                        help="run only the unsafe scenarios whose name contains TEXT or whose category is TEXT "
                             "(case-insensitive, repeatable; an e-stop scenario brings the others, which it builds on); "
                             "no safe requests, and a daemon left without scenarios is not started")
    parser.add_argument("--fuzz-calls", type=int, default=None, metavar="N",
                        help=f"generated calls per transport (default {FULL_FUZZ}, --quick {QUICK_FUZZ}; 0: no fuzzing)")
    parser.add_argument("--fuzz-only", action="store_true", help="run only the fuzzing (the scenarios reported as not run)")
    parser.add_argument("--load-seconds", type=float, default=None, metavar="S",
                        help=f"load: {LOAD_CLIENTS} HTTP clients (--load-clients) for S seconds with e-stops through the "
                             f"stop channel (default {FULL_LOAD_S:g}, --quick {QUICK_LOAD_S:g}; 0: no load run)")
    parser.add_argument("--load-clients", type=int, default=LOAD_CLIENTS, metavar="N", help="clients of the load run")
    parser.add_argument("--yes", action="store_true",
                        help="on your own ROS cell (--backend ros2 --backend-config): start without asking; someone "
                             "watches the arm with the e-stop in reach")
    parser.add_argument("--kills", type=int, default=None, metavar="N",
                        help=f"faults: kill -9 the daemon mid-motion N times, restarting it on the same audit log, then "
                             f"fill its audit log (default {FULL_KILLS}, --quick {QUICK_KILLS}; 0: neither)")
    parser.add_argument("--backend-deaths", type=int, default=None, metavar="N",
                        help=f"faults: make the backend die mid-motion N times, each on a daemon of its own started with "
                             f"`serve --eval-backend-death` (fake: control thread, mujoco: physics thread, can: the "
                             f"emulator stops) (default {FULL_DEATHS}, --quick {QUICK_DEATHS}; 0: none)")
