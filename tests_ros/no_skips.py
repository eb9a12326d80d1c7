"""A pytest plugin for the ROS run of scripts/test.sh: a skipped or xfailed test fails.

The ROS tests must all run in CI (issue #11: "nothing skipped"). A skip there means a missing
interface, endpoint or capability, which is exactly what the run exists to catch, so each skip or
xfail is reported as a failure naming its reason. Load it with ``-p tests_ros.no_skips``.
"""

from __future__ import annotations

from collections.abc import Generator

import pytest


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Generator[None, pytest.TestReport, pytest.TestReport]:
    report = yield
    if report.skipped:
        if hasattr(report, "wasxfail"):
            reason = f"xfailed ({report.wasxfail or 'no reason given'})"
            del report.wasxfail
        else:
            longrepr = report.longrepr
            reason = f"skipped ({longrepr[2] if isinstance(longrepr, tuple) else longrepr})"
        report.outcome = "failed"
        report.longrepr = f"{item.nodeid} was {reason}: nothing may be skipped in the ROS run (tests_ros/no_skips.py)"
    return report


@pytest.hookimpl(wrapper=True)
def pytest_make_collect_report(collector: pytest.Collector) -> Generator[None, pytest.CollectReport, pytest.CollectReport]:
    """A whole module skipped at collection (``pytest.importorskip``, a module-level skip) fails too."""
    report = yield
    if report.skipped:
        longrepr = report.longrepr
        reason = longrepr[2] if isinstance(longrepr, tuple) else longrepr
        report.outcome = "failed"
        report.longrepr = f"{collector.nodeid} was skipped at collection ({reason}): nothing may be skipped in the ROS run"
    return report
