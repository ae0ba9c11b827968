"""The process pool: its shutdown when a worker was reaped by someone else (it must not hang), its warnings."""

import subprocess
import sys
import textwrap
import warnings

import pytest

from uiest.experiments import executors

pytestmark = pytest.mark.slow

GHOST_WORKER = textwrap.dedent(
    """
    import os, signal, time
    from concurrent.futures.process import BrokenProcessPool
    from uiest.experiments import executors

    if __name__ == "__main__":
        pool = executors.spawn_pool(1)
        futures = [pool.submit(time.sleep, 30) for _ in range(4)]
        while not pool._call_queue.full():  # one task running, two queued: no room for a stop sentinel
            time.sleep(0.05)
        (pid,) = list(pool._processes)
        signal.signal(signal.SIGCHLD, signal.SIG_IGN)  # the kernel reaps ended children: the pool's waitpid fails
        os.kill(pid, signal.SIGKILL)
        try:
            futures[0].result()
        except BrokenProcessPool:
            print("broken", flush=True)
        executors.stop_pool(pool, abandon={abandon})
        print("stopped", flush=True)
    """
)


def _run(abandon: bool) -> subprocess.CompletedProcess[str]:
    script = GHOST_WORKER.format(abandon=abandon)
    return subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)


def test_a_broken_pool_whose_worker_was_reaped_elsewhere_stops_and_the_interpreter_exits():
    # before the fix, the pool's manager thread spun forever: stop_pool (wait) or the exit hung
    for abandon in (False, True):
        done = _run(abandon)
        assert done.returncode == 0, done.stderr
        assert done.stdout.split() == ["broken", "stopped"]


def test_a_workers_warnings_are_plain_lines_once_each(capfd):
    # a spawned worker has no CLI around it: its warnings are one line each, without source lines, once per worker
    pool = executors.spawn_pool(1)
    try:
        for _ in range(3):
            pool.submit(warnings.warn, "x_scale: a warning every task repeats", UserWarning).result()
    finally:
        executors.stop_pool(pool, abandon=False)
    err = capfd.readouterr().err
    assert err.count("warning: x_scale: a warning every task repeats") == 1, err
    assert "UserWarning" not in err and "warnings.warn" not in err
