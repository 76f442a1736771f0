"""``teachrepeat replay FILE``: the command line of :mod:`server.recording.replay`.

Heavy imports stay inside :func:`run`, so that building the parser stays cheap.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from server.tuning import add_set_argument

    parser.add_argument("file", type=Path, metavar="FILE", help="a navigation task's recording")
    parser.add_argument(
        "--db",
        type=Path,
        default=None,
        help="the database the recording's tour is in (default: the server's, "
        "data/teachrepeat.sqlite or TEACHREPEAT_DB); copied, never written",
    )
    add_set_argument(
        parser,
        "replay with this navigation setting changed (repeatable; dotted names for nested "
        "ones, values as JSON), on top of those the recording was made with",
    )
    parser.add_argument(
        "--partial",
        action="store_true",
        help="replay the whole frames of a recording that was cut short (the server stopped)",
    )
    parser.add_argument(
        "--tolerance",
        type=_tolerance,
        default=1e-4,
        metavar="REL",
        help="belief, votes and similarities equal within this relative tolerance (default "
        "1e-4: other CPUs sum float32 in another order); actions, edges, images, behaviours "
        "and the task's state are always compared exactly, the command to 1 mm/s and 1 mrad/s; "
        "0: every number equal to the last bit",
    )
    parser.add_argument(
        "--json", type=Path, default=None, help="write the comparison here as JSON (- : stdout)"
    )


def _tolerance(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not 0 <= value < 1:
        raise argparse.ArgumentTypeError(f"{text} is not a relative tolerance in [0, 1)")
    return value


def run(args: argparse.Namespace) -> int:
    """Exit 0: no differences; 1: some frames differ; 2: the file or the database cannot be
    replayed (the message says why)."""
    from server.recording.reader import RecordingError, read_recording
    from server.recording.replay import Tolerance, replay

    prog = "teachrepeat replay"
    db = args.db
    if db is None:
        from server.config import Settings

        db = Settings().db
    try:
        recording = read_recording(args.file)
        report, timing = replay(
            recording,
            db,
            settings=dict(args.settings),
            partial=args.partial,
            tolerance=Tolerance.of(args.tolerance),
        )
    except RecordingError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
    if args.json is not None and str(args.json) == "-":
        print(json.dumps(report.as_json(), indent=2))
    else:
        for line in report.lines():
            print(line)
        if args.json is not None:
            args.json.parent.mkdir(parents=True, exist_ok=True)
            args.json.write_text(json.dumps(report.as_json(), indent=2) + "\n")
    print(timing.text(), file=sys.stderr)
    return 1 if report.differing else 0
