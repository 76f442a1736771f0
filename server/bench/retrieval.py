"""``teachrepeat bench retrieval``: the similarity engine against an OpenCV-only baseline.

On the real images of the shared data folder (corridor, Nordland, triplets, ukbench) and on
synthesised tours of 1 000 / 10 000 / 100 000 images, in one run, side by side:

* **engine** - :mod:`server.vision` with its defaults (``--descriptor`` changes the local
  features; plus variants: geometric check on, 50 features, ORB descriptor, default vs learned
  weights);
* on the synthesised tours also the **exhaustive first pass against the inverted files**
  (:mod:`server.vision.inverted`) on the same tour and queries, and which one the engine picks
  at that size (``engine.speed.<n>.automatic``);
* **baseline** - what a user would write with OpenCV alone: ORB with 500 features,
  brute-force Hamming ``knnMatch(k=2)`` with Lowe's ratio test (0.75) against every stored
  image, best = most good matches.

Output: a table on stdout and, with ``--json OUT``, ``{"engine": {...}, "baseline": {...},
"variants": {...}, "meta": {...}}`` with the dotted names of docs/retrieval.md as nested
objects. ``--plot PNG`` draws recall@1 against the frame tolerance on Nordland (OpenCV drawing).

Timing is single-threaded: OpenCV and BLAS are limited to one thread before NumPy is imported
(when the bench is the first to import it).
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Any

from server.bench.common import DESCRIPTOR_CHOICES

DEFAULT_SIZES = "1000,10000,100000"


def _default_data() -> str:
    return os.environ.get("TEACHREPEAT_DATA", "../shared/data")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``teachrepeat bench retrieval``."""
    parser.add_argument(
        "--data",
        default=_default_data(),
        help="data folder with corridor/, nordland/, triplets/, ukbench/ "
        "(default: $TEACHREPEAT_DATA or ../shared/data)",
    )
    parser.add_argument("--json", dest="json_out", default=None, help="write results to this file")
    parser.add_argument("--plot", default=None, help="write the Nordland recall plot (PNG)")
    parser.add_argument(
        "--quick",
        action="store_true",
        help="smoke run: subsets of the data, small tours, few queries (seconds, not minutes)",
    )
    parser.add_argument(
        "--sizes",
        default=None,
        help=f"comma-separated tour sizes for the speed test (default {DEFAULT_SIZES}; "
        "--quick: 300)",
    )
    parser.add_argument(
        "--queries", type=int, default=200, help="timed engine queries per tour size"
    )
    parser.add_argument(
        "--baseline-queries",
        default="20,5,2",
        help="timed baseline queries for the 1st, 2nd, 3rd... tour size (the baseline takes "
        "seconds per query on large tours; 0 skips the baseline at that size)",
    )
    parser.add_argument(
        "--images-per-state",
        type=int,
        default=100,
        help="synthesised tours: consecutive images per upper state",
    )
    parser.add_argument(
        "--pool", type=int, default=3000, help="distinct synthesised images tiled into tours"
    )
    parser.add_argument(
        "--no-variants",
        action="store_true",
        help="skip the engine variants (faster; the inverted-files one still runs, ~20 s)",
    )
    parser.add_argument(
        "--descriptor",
        choices=DESCRIPTOR_CHOICES,
        default="grad36",
        help="local features of the engine, FeatureParams.descriptor (default grad36)",
    )


def run(args: argparse.Namespace) -> int:
    """Run the benchmark; returns the process exit code."""
    from server.bench import _retrieval_impl as impl

    data = Path(args.data)
    if not (data / "corridor").is_dir():
        print(
            f"error: no corridor/ in data folder {data.resolve()}; "
            "pass --data DIR or set TEACHREPEAT_DATA"
        )
        return 2
    results: dict[str, Any] = impl.run_all(args)
    print(impl.format_table(results))
    if args.json_out:
        impl.write_json(results, Path(args.json_out))
        print(f"wrote {args.json_out}")
    if args.plot:
        impl.plot_nordland(results, Path(args.plot))
        print(f"wrote {args.plot}")
    return 0
