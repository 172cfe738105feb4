"""Progress bars (ctfit/_runtime/progress.py): when they show, and ``make report``'s bar over its steps."""

import pytest

from ctfit._runtime import progress
from ctfit._runtime.progress import ProgressLines, bar, echo, progress_enabled, progress_mode

from conftest import load_script


@pytest.mark.parametrize(
    "env, quiet, expected",
    [(None, False, False), ("1", False, True), ("0", False, False), ("1", True, False)],
)
def test_progress_only_on_a_terminal_unless_forced_and_never_when_quiet(monkeypatch, env, quiet, expected):
    if env is None:
        monkeypatch.delenv("CTFIT_PROGRESS", raising=False)
    else:
        monkeypatch.setenv("CTFIT_PROGRESS", env)
    assert progress_enabled(quiet) is expected  # pytest's stderr is no terminal


def test_a_disabled_bar_is_the_iterable_itself():
    items = [1, 2, 3]
    assert bar(items, desc="x", enabled=False) is items


def test_echo_clears_a_shown_bar_before_its_line(capsys):
    for i in bar(range(2), desc="work", enabled=True, leave=True):
        echo(f"line {i}", err=True)
    err = capsys.readouterr().err
    lines = [line.split("\r")[-1] for line in err.split("\n")]
    assert "line 0" in lines and "line 1" in lines
    assert "work:" in err and "2/2" in err


@pytest.fixture
def report(monkeypatch):
    module = load_script("report")
    plan = [("one", [["-c", "print('output of step one')"]]), ("two", [["-c", "import sys; sys.exit(3)"]]), ("three", [["-c", "print('never')"]])]
    monkeypatch.setattr(module, "steps", lambda docs, small, scratch: plan)
    return module


@pytest.mark.parametrize("forced", ["1", "0"])
def test_report_runs_its_steps_with_or_without_a_bar(report, monkeypatch, capfd, tmp_path, forced):
    monkeypatch.setenv("CTFIT_PROGRESS", forced)
    assert report.main(["--docs", str(tmp_path)]) == 3  # the failing step's status; the next step never runs
    out, err = capfd.readouterr()
    assert "output of step one" in out and "== two: exit 3" in out and "never" not in out
    assert ("report:" in err and "1/3" in err) is (forced == "1")


def test_report_quiet_has_no_bar(report, monkeypatch, capfd, tmp_path):
    monkeypatch.setenv("CTFIT_PROGRESS", "1")
    report.main(["--docs", str(tmp_path), "-q"])
    assert "report:" not in capfd.readouterr().err


@pytest.mark.parametrize("env, quiet, expected", [(None, False, "lines"), ("1", False, "bar"), ("0", False, None), (None, True, None), ("1", True, None)])
def test_long_work_writes_lines_where_stderr_is_no_terminal(monkeypatch, env, quiet, expected):
    """A bar on a terminal (or forced); plain lines into a log file or a pipe; nothing when quiet."""
    if env is None:
        monkeypatch.delenv("CTFIT_PROGRESS", raising=False)
    else:
        monkeypatch.setenv("CTFIT_PROGRESS", env)
    assert progress_mode(quiet) == expected


def test_progress_lines_say_how_far_and_how_long_is_left(monkeypatch, capsys):
    clock = iter([0.0, 1.0, 2.0, 7.0, 8.0, 12.5, 0.0])  # the start, then one reading per update (and the last line's start)
    monkeypatch.setattr(progress.time, "monotonic", lambda: next(clock))
    lines = ProgressLines(1000, desc="sampling", done=200)  # resumed: 200 steps were done before
    for _ in range(5):
        lines.update(100)
    err = capsys.readouterr().err.splitlines()
    # One line at most every LINE_EVERY_S (5 s): after 7 s and after 12.5 s; the rate counts this run's steps only.
    assert err == ["sampling: 500 of 1,000 steps (50 %), 7 s, about 12 s left", "sampling: 700 of 1,000 steps (70 %), 12 s, about 8 s left"]
    assert ProgressLines(10, desc="x").line(3725.0).endswith("1 h 02 min")
