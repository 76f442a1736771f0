"""``teachrepeat bench upload``: the frames/s the robot client reaches when teaching real frames.

Each run starts a real server on a fresh database file, registers a robot and teaches the 111
frames of ``corridor/ref`` (4 places) through the robot client, over loopback HTTP.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from server.bench.common import corridor_marks, default_data_dir, stats, write_json


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", type=Path, default=None, help="image data folder")
    parser.add_argument("--runs", type=int, default=5, help="teaching runs (default 5)")
    parser.add_argument("--json", type=Path, default=None, help="write the results here")


def run(args: argparse.Namespace) -> int:
    from robot_client.client import TeachRepeatClient
    from robot_client.teach import teach_folder
    from server.process import scratch_server

    frames = (args.data or default_data_dir()) / "corridor" / "ref"
    if not frames.is_dir():
        print(f"no frames at {frames}; pass --data DIR")
        return 2
    marks = corridor_marks()
    rates: list[float] = []
    for k in range(args.runs):
        with (
            scratch_server("bench.sqlite") as server,
            TeachRepeatClient(server.url, server.register_robot("bench")) as client,
        ):
            report = teach_folder(
                client, tour=f"corridor-{k}", frames=frames, marks=marks, progress=False
            )
        rates.append(report.frames_per_second)
        print(
            f"run {k + 1}: {report.uploaded} frames in {report.seconds:.3f} s = "
            f"{report.frames_per_second:.0f} frames/s"
        )
    summary = stats(rates)
    print(
        f"upload rate over {args.runs} runs: median {summary['p50']:.0f} frames/s "
        f"(min {min(rates):.0f}, max {max(rates):.0f})"
    )
    write_json(
        args.json,
        {
            "frames": 111,
            "runs": args.runs,
            "frames_per_second": summary,
            "per_run": rates,
            "target_frames_per_second": 100,
        },
    )
    return 0
