"""Count how uiest meets bad input: typed error, recorded outcome, raw traceback or silent result.

Run: ``python bench/bad_inputs.py``. Runs every case of ``tests/bad_inputs.py`` (API calls and
``uiest`` invocations) and prints the counts and every case that is not a typed error or a
recorded outcome.
"""

from __future__ import annotations

import sys
import tempfile
from collections import Counter
from pathlib import Path

from typer.testing import CliRunner

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from bad_inputs import api_cases, classify, cli_cases

from uiest.cli import app


def cli_verdict(case) -> tuple[str, str]:  # type: ignore[no-untyped-def]
    result = CliRunner().invoke(app, list(case.args))
    text = result.output + (result.stderr if result.stderr_bytes is not None else "")
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        return "traceback", repr(result.exception)
    if result.exit_code == case.code and case.match in text:
        return "good", text.strip().splitlines()[-1] if text.strip() else ""
    return "silent", f"exit {result.exit_code}: {text.strip()[:200]}"


def main() -> None:
    tmp = Path(tempfile.mkdtemp(prefix="uiest-bad-inputs-"))
    counts: Counter[str] = Counter()
    lines = []
    for case in api_cases(tmp):
        verdict, detail = classify(case)
        counts[verdict] += 1
        if verdict not in ("good", "handled"):
            lines.append(f"  API {case.name}: {verdict}: {detail}")
    for case in cli_cases(tmp):
        verdict, detail = cli_verdict(case)
        counts[verdict] += 1
        if verdict != "good":
            lines.append(f"  CLI {case.name}: {verdict}: {detail}")
    total = sum(counts.values())
    print(f"{total} bad inputs: good (typed error) {counts['good']}, handled (recorded) {counts['handled']}, "
          f"traceback {counts['traceback']}, silent {counts['silent']}")  # fmt: skip
    print("\n".join(lines))


if __name__ == "__main__":
    main()
