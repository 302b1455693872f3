"""mypy against a baseline: fail on any type error that is not in mypy-baseline.txt.

mypy came to dkfsim after most of its code: the public API is annotated and checked
strictly (pyproject.toml, ``[tool.mypy]``), and the errors the rest had then are listed
in ``mypy-baseline.txt``, without line numbers so that edits elsewhere in a file do not
disturb them.  Errors are compared by file and error code (``[arg-type]``), not by their
wording, which changes between mypy and numpy versions.  ``make lint`` runs this script:

* more errors of a code in a file than the baseline lists fails (fix them; never add them);
* fewer fails too, so that the baseline only shrinks: ``python tools/mypy_baseline.py
  --update`` rewrites it after a fix.
"""

from __future__ import annotations

import re
import subprocess
import sys
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BASELINE = ROOT / "mypy-baseline.txt"
LINE = re.compile(r"^(?P<path>[^:\s]+\.py):\d+(?::\d+)?: error: (?P<message>.*)$")
CODE = re.compile(r"\[(?P<code>[a-z-]+)\]\s*$")


def key(error: str) -> str:
    """``path [code]``: what errors are compared by."""
    path, _, message = error.partition(": ")
    m = CODE.search(message)
    return f"{path} [{m['code'] if m else '?'}]"


def current() -> list[str]:
    """The errors mypy reports now, as ``path: message [code]`` lines."""
    p = subprocess.run([sys.executable, "-m", "mypy", "--no-error-summary", "--no-pretty"], cwd=ROOT,
                       capture_output=True, text=True)
    if p.returncode > 1:                         # 2: mypy itself failed (bad configuration, crash)
        sys.exit(f"mypy did not run: {p.stderr.strip() or p.stdout.strip()}")
    found = [LINE.match(line) for line in p.stdout.splitlines()]
    return sorted(f"{m['path']}: {m['message']}" for m in found if m)


def main(argv: list[str]) -> int:
    errors = current()
    if argv[1:] == ["--update"]:
        BASELINE.write_text("".join(f"{e}\n" for e in errors))
        print(f"mypy-baseline.txt: {len(errors)} errors")
        return 0
    listed = [line for line in BASELINE.read_text().splitlines() if line.strip()]
    baseline, now = Counter(map(key, listed)), Counter(map(key, errors))
    new, gone = now - baseline, baseline - now
    for k in sorted(new):
        print(f"new type errors: {k}, {new[k]} more than mypy-baseline.txt lists:")
        for e in errors:
            if key(e) == k and e not in listed:
                print(f"  {e}")
    if gone:
        print(f"{sum(gone.values())} errors of mypy-baseline.txt no longer occur (fixed): "
              "run `python tools/mypy_baseline.py --update` to shrink the baseline")
    if not new and not gone:
        print(f"mypy: no type errors beyond the {len(listed)} of mypy-baseline.txt")
    return 1 if new or gone else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
