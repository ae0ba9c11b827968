"""Third round of bad inputs (issue 35): each case in a worker process, classified automatically.

Run: ``PYTHONPATH=src python bench/bad_inputs_round3.py [--jobs 2] [--timeout 60] [--only SUBSTRING]``.

The cases live in ``bench/bad_inputs_round3_cases.py`` (none taken from ``tests/bad_inputs.py``). Each runs in a
long-lived worker process (``--worker``) that is killed and replaced when a case exceeds the timeout ("slow") or
when the process dies ("crash"). Inside the worker a case is classified as

- good: a typed :mod:`uiest.errors` error whose message names the argument (the case's ``names`` pattern), a CLI
  exit with an ``error:`` line naming it, or a returned result the case's check accepts;
- handled: a typed error (or ``error:`` line) that does not name the argument, or a questionable result returned
  with a ``UserWarning`` (not a numpy ``RuntimeWarning``);
- traceback: any other exception (or a CLI traceback);
- silent: a result returned without error or warning that the case's check rejects (the check says what a correct
  result is; e.g. NaN estimates labelled converged, data read as something else, files outside the output folder),
  or a CLI exit without any message;
- slow: over the timeout (default 60 s); crash: the worker process died.

Prints the counts per class and one line per non-good case: id, what was given, what happened.
"""

from __future__ import annotations

import argparse
import json
import os
import queue
import re
import resource
import select
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import traceback
import warnings
from collections import Counter
from pathlib import Path

HERE = Path(__file__).resolve().parent
CLASSES = ("good", "handled", "traceback", "silent", "slow", "crash")
MEMORY_LIMIT = 6 * 2**30  # bytes of address space per worker: a runaway allocation fails instead of swapping the host


# ------------------------------------------------------------------------------------------------ worker side
def classify(case) -> tuple[str, str]:  # type: ignore[no-untyped-def]
    """Run one case in this process: (class, detail)."""
    from uiest.errors import UiestError

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            result = case.call()
        except UiestError as exc:
            text = f"{type(exc).__name__}: {exc}".replace("\n", " ")
            if case.check is not None and case.error_ok is False:
                return "handled", f"refused a valid input: {text}"
            if re.search(case.names, str(exc), flags=re.IGNORECASE):
                return "good", text
            return "handled", f"does not name {case.names!r}: {text}"
        except Exception as exc:  # any other exception is what this harness counts
            frame = traceback.extract_tb(exc.__traceback__)[-1]
            where = f"{Path(frame.filename).name}:{frame.lineno}"
            return "traceback", f"{type(exc).__name__}: {str(exc)[:200]} (at {where})".replace("\n", " ")
    user_warnings = [w for w in caught if issubclass(w.category, UserWarning)]
    if getattr(result, "is_cli", False):
        return _classify_cli(case, result)
    if case.check is None:
        return "silent", f"returned {_short(result)} without an error"
    try:
        why = case.check(result)
    except Exception as exc:  # a result the check cannot even read is meaningless
        why = f"the result could not be checked ({type(exc).__name__}: {exc})"
    if why is None:
        return "good", f"returned {_short(result)} (checked)"
    if user_warnings:
        message = str(user_warnings[0].message)
        if case.warning_suffices and re.search(case.names, message, flags=re.IGNORECASE):
            return "good", f"{why}; warned as specified: {message[:150]}"
        return "handled", f"{why}; warned: {message[:150]}"
    return "silent", why


def _classify_cli(case, res) -> tuple[str, str]:  # type: ignore[no-untyped-def]
    text = res.text
    if res.exception is not None:
        return "traceback", f"{res.exception} (exit {res.code})"
    if "Traceback (most recent call last)" in text:
        last = [line for line in text.strip().splitlines() if line.strip()][-1]
        return "traceback", f"exit {res.code}: {last[:200]}"
    errors = [line for line in text.splitlines() if line.startswith(("error:", "Error", "│ ", "Usage:"))]
    if res.code != 0:
        message = " ".join(line.strip() for line in text.splitlines() if line.strip())[-300:]
        if not message:
            return "silent", f"exit {res.code} with no message"
        if case.check is not None and case.error_ok is False:
            return "handled", f"refused a valid input: exit {res.code}: {message}"
        if errors and re.search(case.names, text, flags=re.IGNORECASE):
            return "good", f"exit {res.code}: {message[:200]}"
        return "handled", f"exit {res.code}, does not name {case.names!r}: {message[:200]}"
    if case.check is None:
        return "silent", f"exit 0 without an error: {text.strip()[-200:]!r}"
    try:
        why = case.check(res)
    except Exception as exc:
        why = f"the output could not be checked ({type(exc).__name__}: {exc})"
    if why is None:
        return "good", "exit 0 (checked)"
    if "warning:" in text:
        return "handled", f"{why}; warned"
    return "silent", why


def _short(value: object) -> str:
    text = repr(value).replace("\n", " ")
    return text[:120] + ("..." if len(text) > 120 else "")


def worker() -> None:
    """Read case ids on stdin, write one JSON line per case on the original stdout (library output is discarded)."""
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))
    out = os.fdopen(os.dup(1), "w", buffering=1)
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)
    os.dup2(devnull, 2)
    sys.path.insert(0, str(HERE))
    import bad_inputs_round3_cases as cases_module

    by_id = {case.id: case for case in cases_module.cases()}
    for line in sys.stdin:
        case_id = line.strip()
        if not case_id:
            continue
        start = time.monotonic()
        with cases_module.scratch_for(case_id):
            verdict, detail = classify(by_id[case_id])
        out.write(json.dumps({"id": case_id, "class": verdict, "detail": detail,
                              "seconds": time.monotonic() - start}) + "\n")  # fmt: skip


# ------------------------------------------------------------------------------------------------ parent side
def worker_env() -> dict[str, str]:
    """The environment with PYTHONPATH made absolute (workers run each case in its own scratch folder)."""
    env = os.environ.copy()
    paths = [str(Path(p).resolve()) for p in env.get("PYTHONPATH", "").split(os.pathsep) if p]
    env["PYTHONPATH"] = os.pathsep.join(paths)
    return env


class Worker:
    def __init__(self) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, str(Path(__file__).resolve()), "--worker"], stdin=subprocess.PIPE,
            stdout=subprocess.PIPE, text=True, bufsize=1, start_new_session=True, env=worker_env(),
        )  # fmt: skip

    def run(self, case_id: str, timeout: float) -> dict:  # type: ignore[type-arg]
        assert self.proc.stdin is not None and self.proc.stdout is not None
        start = time.monotonic()
        try:
            self.proc.stdin.write(case_id + "\n")
            self.proc.stdin.flush()
        except BrokenPipeError:
            return self._died(case_id, start)
        ready, _, _ = select.select([self.proc.stdout], [], [], timeout)
        if not ready:
            self.kill()
            return {"id": case_id, "class": "slow", "detail": f"still running after {timeout:.0f} s (killed)",
                    "seconds": time.monotonic() - start}  # fmt: skip
        line = self.proc.stdout.readline()
        if not line:
            return self._died(case_id, start)
        return json.loads(line)

    def _died(self, case_id: str, start: float) -> dict:  # type: ignore[type-arg]
        code = self.proc.wait()
        how = f"signal {signal.Signals(-code).name}" if code < 0 else f"exit code {code}"
        return {"id": case_id, "class": "crash", "detail": f"the process died ({how})",
                "seconds": time.monotonic() - start}  # fmt: skip

    def kill(self) -> None:
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)  # the worker's own session: it and any child it started
            self.proc.wait()

    def close(self) -> None:
        if self.proc.poll() is None:
            assert self.proc.stdin is not None
            self.proc.stdin.close()
            try:
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.kill()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--timeout", type=float, default=60.0, help="seconds before a case counts as slow")
    parser.add_argument("--only", default="", help="run the cases whose id contains this")
    parser.add_argument("--json", type=Path, help="also write every case's outcome as JSON")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        worker()
        return
    os.environ["UIEST_R3_SCRATCH"] = tempfile.mkdtemp(prefix="uiest-bad-inputs-r3-")  # every worker's cases
    sys.path.insert(0, str(HERE))
    import bad_inputs_round3_cases as cases_module

    all_cases = [case for case in cases_module.cases() if args.only in case.id]
    ids = [case.id for case in all_cases]
    if len(set(ids)) != len(ids):
        raise SystemExit(f"repeated case ids: {[i for i in ids if ids.count(i) > 1]}")
    given = {case.id: case.given for case in all_cases}
    todo: queue.Queue[str] = queue.Queue()
    for case_id in ids:
        todo.put(case_id)
    outcomes: dict[str, dict] = {}  # type: ignore[type-arg]
    lock = threading.Lock()
    start = time.monotonic()

    def job() -> None:
        current = Worker()
        try:
            while True:
                try:
                    case_id = todo.get_nowait()
                except queue.Empty:
                    return
                outcome = current.run(case_id, args.timeout)
                if outcome["class"] in ("slow", "crash"):
                    current.kill()
                    current = Worker()
                with lock:
                    outcomes[case_id] = outcome
                    print(f"[{len(outcomes)}/{len(ids)}] {case_id}: {outcome['class']} ({outcome['seconds']:.1f} s)",
                          file=sys.stderr, flush=True)  # fmt: skip
        finally:
            current.close()

    threads = [threading.Thread(target=job) for _ in range(max(1, args.jobs))]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    counts = Counter(outcome["class"] for outcome in outcomes.values())
    print(f"{len(ids)} bad inputs in {time.monotonic() - start:.0f} s: "
          + ", ".join(f"{name} {counts[name]}" for name in CLASSES))  # fmt: skip
    for case_id in ids:
        outcome = outcomes[case_id]
        if outcome["class"] != "good":
            print(f"  {outcome['class']:9s} {case_id} | {given[case_id]} | {outcome['detail']}")
    shutil.rmtree(os.environ["UIEST_R3_SCRATCH"], ignore_errors=True)
    if args.json:
        args.json.write_text(json.dumps([{**outcomes[i], "given": given[i]} for i in ids], indent=1))


if __name__ == "__main__":
    main()
