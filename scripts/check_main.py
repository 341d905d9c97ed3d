"""The command-line frame the `check_*.py` scripts share: one directory argument, a list of
failures, one line per failure on stderr, exit status 0 (all good), 1 (failures) or 2 (usage).
"""

import pathlib
import sys


def run(name, doc, check, argv, ok_detail=lambda: ""):
    """Runs `check(directory)` (which returns a list of failure strings) on argv[1] and reports.

    `doc` is the script's docstring, whose third line is its usage; `ok_detail()` adds to the
    success line. Unreadable or malformed input counts as a failure, not a crash.
    """
    if len(argv) != 2:
        print(doc.strip().splitlines()[2], file=sys.stderr)
        return 2
    directory = pathlib.Path(argv[1])
    try:
        failures = check(directory)
    except (OSError, ValueError, KeyError) as error:
        failures = [f"{directory}: {error}"]
    for failure in failures:
        print(f"{name}: FAIL: {failure}", file=sys.stderr)
    if not failures:
        print(f"{name}: {directory} OK{ok_detail()}")
    return 1 if failures else 0
