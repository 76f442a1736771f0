"""``teachrepeat demo``: for now, the server on the embedded SQLite default.

The closed-loop issue turns this into the full simulated demo (teach a simulated home, then
send the robot to three places).
"""

from __future__ import annotations

import argparse

from server import serve


def add_arguments(parser: argparse.ArgumentParser) -> None:
    serve.add_arguments(parser)


def run(args: argparse.Namespace) -> int:
    return serve.run(args)
