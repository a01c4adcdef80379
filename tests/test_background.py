"""The second planning process (controllers/background.py): its answer, its errors, and
that it never outlives its parent: leaving the block, SIGTERM, Ctrl-C, SIGKILL."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import background_jobs as jobs
import pytest

from controllers import background
from controllers.background import Background
from toggle.interrupts import Terminated

pytestmark = pytest.mark.real_time

TESTS = Path(__file__).parent


def alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie counts as gone)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except FileNotFoundError:
        return False
    return state != "Z"


def wait_for(predicate, timeout: float = 20.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(0.02)
    return False


def planning_children(pid: int) -> list[int]:
    """The processes ``pid`` spawned to plan (not a compiler, not multiprocessing's
    resource tracker)."""
    found = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        for child in (task / "children").read_text().split():
            try:
                command = Path(f"/proc/{child}/cmdline").read_bytes()
            except FileNotFoundError:
                continue
            found += [int(child)] if b"spawn_main" in command else []
    return found


@pytest.fixture
def two_cores(monkeypatch):
    monkeypatch.setattr(background, "parallel", lambda: True)


def test_the_answer_and_the_ticks_come_from_a_second_process(two_cores):
    with Background(jobs.count, 5) as job:
        answer = job.result()
        assert answer == {"n": 5, "pid": answer["pid"]} and answer["pid"] != os.getpid()
        assert job.ticks() == 5


def test_one_core_runs_the_job_here_when_asked(monkeypatch):
    monkeypatch.setattr(background, "parallel", lambda: False)
    with Background(jobs.count, 3) as job:
        assert job.ticks() == 0  # nothing runs before the result is asked for
        assert job.result() == {"n": 3, "pid": os.getpid()} and job.ticks() == 3


def test_the_childs_error_is_raised_here(two_cores):
    with Background(jobs.refuse, "no stroke meets 1 N") as job, pytest.raises(
            ValueError, match="no stroke meets 1 N"):
        job.result()


def test_leaving_the_block_stops_the_child(two_cores, tmp_path):
    pid_file = tmp_path / "pid"
    with pytest.raises(RuntimeError), Background(jobs.sleep_forever, str(pid_file)):
        assert wait_for(pid_file.exists)
        raise RuntimeError("the parent's own work failed")
    assert not alive(int(pid_file.read_text()))


def test_sigterm_in_the_block_is_terminated_and_stops_the_child(two_cores, tmp_path):
    pid_file = tmp_path / "pid"
    before = signal.getsignal(signal.SIGTERM)
    with pytest.raises(Terminated), Background(jobs.sleep_forever, str(pid_file)) as job:
        assert wait_for(pid_file.exists)
        os.kill(os.getpid(), signal.SIGTERM)
        job.result()
    assert not alive(int(pid_file.read_text()))
    assert signal.getsignal(signal.SIGTERM) is before  # restored


def test_a_killed_parent_takes_the_child_with_it(tmp_path):
    """SIGKILL leaves no handler to run: the kernel ends the child (PR_SET_PDEATHSIG)."""
    pid_file = tmp_path / "pid"
    script = textwrap.dedent(f"""
        import sys, time
        sys.path.insert(0, {str(TESTS)!r})
        import background_jobs
        from controllers import background
        background.parallel = lambda: True
        with background.Background(background_jobs.sleep_forever, {str(pid_file)!r}):
            time.sleep(60)
    """)
    parent = subprocess.Popen([sys.executable, "-c", script])
    try:
        assert wait_for(pid_file.exists)
        child = int(pid_file.read_text())
        assert alive(child)
        parent.kill()
        parent.wait()
        assert wait_for(lambda: not alive(child), 10)
    finally:
        parent.kill()


@pytest.mark.alone  # two IPOPT processes on the two cores: beside a rig test they starved it
@pytest.mark.parametrize("how, after, status, said", [
    ("sigterm", 1.0, 128 + signal.SIGTERM, "toggle plan: terminated"),
    ("ctrl-c", 1.0, 130, "toggle plan: interrupted"),
    # the child's start-up (its imports take seconds on a loaded machine): a Ctrl-C there
    # ended it with a traceback and toggle with exit status 1
    ("ctrl-c", 0.0, 130, "toggle plan: interrupted"),
    ("ctrl-c", 0.1, 130, "toggle plan: interrupted"),
])
def test_toggle_plan_trade_off_stopped_leaves_no_process(how, after, status, said):
    """SIGTERM to toggle, or Ctrl-C to its process group (the terminal's), ``after`` seconds
    into the dry cycle's process (at its start-up, or well into the solves): the exit status
    says so, nothing else is said, and that process is gone."""
    toggle = Path(sys.executable).with_name("toggle")
    proc = subprocess.Popen([str(toggle), "plan", "--trade-off", "6", "--json"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        # (a cold cache compiles the problem first, for a minute on a loaded machine)
        assert wait_for(lambda: proc.poll() is not None or bool(planning_children(proc.pid)),
                        300)
        helpers = planning_children(proc.pid)
        assert helpers, "no planning process was started"
        time.sleep(after)
        if how == "sigterm":
            proc.send_signal(signal.SIGTERM)
        else:
            os.killpg(proc.pid, signal.SIGINT)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == status and out == "", err
    assert err.strip().splitlines()[-1] == said and "Traceback" not in err
    assert wait_for(lambda: not any(alive(pid) for pid in helpers), 5)


@pytest.mark.parametrize("parallel", [True, False])
def test_the_jobs_solves_join_the_parents_progress(monkeypatch, parallel):
    """Issue 37: a robust plan's bar counts its nominal twin's solves in the second process
    too: the job's announced and counted solves reach the parent's progress (count and
    total, hence the ETA), in a second process or here."""
    from controllers.progress import Progress, reporting

    monkeypatch.setattr(background, "parallel", lambda: parallel)
    with reporting(Progress("planning", enabled=False)) as bar:
        bar.expect(2)
        with Background(jobs.solves, 3) as job:
            bar.advance()  # the parent's own count drains what has come meanwhile
            assert job.result() == 3 and job.ticks() == 3
        bar.advance()
        assert (bar.n, bar.total) == (5, 5)
    assert bar._sources == []  # the job is no source of it after its block


@pytest.mark.parametrize(("here", "expected", "job_solves"), [
    (True, 5, 3), (True, 2, 3), (False, 4, 4)])
def test_a_jobs_solves_announced_ahead_are_in_the_total_from_the_start(
        monkeypatch, here, expected, job_solves):
    """Issue 45: a robust plan's nominal twin, solved after the robust plan, was counted only
    when it began, so the first ETAs left its solves out (65 % short). Announced ahead
    (``expected``), they are in the total at once; the job's own announcement is counted
    against them (no double count); what it never announced leaves the total at the end."""
    from controllers.progress import Progress, reporting

    monkeypatch.setattr(background, "parallel", lambda: True)
    with reporting(Progress("planning", enabled=False)) as bar:
        bar.expect(4)  # the parent's own solves
        with Background(jobs.solves, job_solves, here=here, expected=expected) as job:
            assert bar.total == 4 + expected  # before the job announced anything
            bar.advance(4)
            assert job.result() == job_solves
            bar.advance(0)  # drains the child's counts
            assert bar.total == 4 + max(expected, job_solves)
        assert (bar.n, bar.total) == (4 + job_solves, 4 + job_solves)


def test_a_job_runs_its_own_jobs_in_its_process(two_cores):
    with Background(jobs.nested) as job:
        assert job.result() is False
