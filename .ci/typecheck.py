"""The type-check ratchet of `make lint`: mypy over the packages, held to the error counts recorded per file.

Modules listed as strict in pyproject.toml (`[[tool.mypy.overrides]]`) must have no error at all. Everywhere else
the count of errors of each file may only fall: a file with more errors than `.ci/mypy-baseline.json` records (or
a new file with any) fails the check, naming the errors. When counts fall, `--update` writes the lower counts, so
the ratchet tightens; it never raises one.

    python .ci/typecheck.py            # check (what make lint runs)
    python .ci/typecheck.py --update   # record lower counts after fixing errors
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BASELINE = ROOT / ".ci" / "mypy-baseline.json"
ERROR = re.compile(r"^(?P<file>[^:]+\.py):(?P<line>\d+): error: (?P<text>.*)$")


def run_mypy() -> tuple[Counter, dict[str, list[str]]]:
    proc = subprocess.run([sys.executable, "-m", "mypy"], cwd=ROOT, capture_output=True, text=True)
    if proc.returncode not in (0, 1):  # 2: mypy itself failed (bad config, crash)
        sys.exit(f"mypy failed ({proc.returncode}): {(proc.stderr or proc.stdout).strip().splitlines()[-1:]}")
    counts: Counter = Counter()
    errors: dict[str, list[str]] = {}
    for line in proc.stdout.splitlines():
        match = ERROR.match(line)
        if match:
            counts[match["file"]] += 1
            errors.setdefault(match["file"], []).append(line)
    return counts, errors


def main(argv: list[str]) -> int:
    update = "--update" in argv
    counts, errors = run_mypy()
    if update and not BASELINE.exists():
        BASELINE.write_text(json.dumps(dict(sorted(counts.items())), indent=1) + "\n")
        print(f"ratchet started: {sum(counts.values())} type errors in {len(counts)} files recorded")
        return 0
    recorded = json.loads(BASELINE.read_text()) if BASELINE.exists() else {}
    worse = {f: n for f, n in counts.items() if n > recorded.get(f, 0)}
    if worse:
        for path, n in sorted(worse.items()):
            print(f"{path}: {n} type errors, the ratchet allows {recorded.get(path, 0)}:")
            print("\n".join(f"  {e}" for e in errors[path]))
        print("make lint: type errors above the ratchet (.ci/mypy-baseline.json); fix them, never raise the counts")
        return 1
    better = {f: n for f, n in recorded.items() if counts.get(f, 0) < n}
    if update and (better or recorded.keys() - counts.keys()):
        BASELINE.write_text(json.dumps(dict(sorted(counts.items())), indent=1) + "\n")
        print(f"ratchet tightened: {sum(recorded.values())} → {sum(counts.values())} type errors recorded")
    elif better:
        print(f"{len(better)} files have fewer type errors than recorded: run `python .ci/typecheck.py --update`")
    print(f"type check: {sum(counts.values())} errors in {len(counts)} files, none above the ratchet")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
