"""``teachrepeat bench navigate``: closed-loop navigation in simulated homes, across homes and
conditions in one run.

Per plan: one teaching tour (the plan's route, walked in the home as taught), then N trials in
each chosen condition, each from a random free pose (every fourth one beside a look-alike place,
when the plan has some) to a random place. The robot is carried to its start without being
told: every trial starts with a kidnapping. Success = the robot says "arrived" within 0.5 m of
the place. A trial's start, goal and noise depend only on the seed and its number (the same in
every condition, so conditions compare trial by trial), and its outcome does not depend on which
other trials run, in what order or on how many workers (``server.bench.nav_sweep``).

Per plan x condition the JSON has trials, successes, the success rate with its Wilson 95 %
interval, wrong arrivals, median and p90 path ratio, median time (robot seconds) and the failures
counted by cause and by the behaviour active at the end; pooled figures follow. With one plan
and one condition the same figures are also at the top level (the keys of earlier versions).

``--generated K`` adds K generated homes (``robot_client.sim.generate``, seeds ``1000 * seed + k``)
run exactly as plan files are; the JSON names each by seed and SHA-256 (``generated``).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from server.bench.common import stats, wilson_interval, write_json
from server.bench.nav_ambiguity import localisation_summary

if TYPE_CHECKING:
    from robot_client.sim.generate import GeneratedHome

CONDITIONS = ("same", "lighting", "moved")
DEFAULT_CACHE = Path("data") / "cache" / "tours"
"""Tour recordings, relative to the working directory (``--cache``)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from robot_client.sim.check_plan import add_plan_argument
    from robot_client.sim.generate import add_bench_arguments
    from server.tuning import add_set_argument

    add_plan_argument(parser, several=True)
    add_bench_arguments(parser)
    parser.add_argument(
        "--condition",
        nargs="+",
        choices=CONDITIONS,
        default=["same"],
        help="how the home differs from when it was taught (several: each in turn)",
    )
    parser.add_argument("--trials", type=int, default=50, help="trials per plan and condition")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--max-steps", type=int, default=1500, help="frames per trial at most")
    parser.add_argument(
        "--workers",
        type=int,
        default=1,
        help="trials run in this many processes, each with its own server (same outcomes)",
    )
    parser.add_argument(
        "--only",
        type=_trial_list,
        default=None,
        help="run only these trial numbers (comma-separated, e.g. 2,5,14): each goes exactly "
        "as it does in the full run",
    )
    parser.add_argument(
        "--no-depth",
        action="store_true",
        help="a robot without a depth sensor (one web-cam): the tour is taught and every trial "
        "driven without depth profiles; obstacle avoidance then rests on the bump and stall "
        "behaviours",
    )
    parser.add_argument("--json", type=Path, default=None, help="write the results here")
    add_set_argument(
        parser,
        "run the servers with this navigation setting changed (repeatable; dotted names "
        "for nested ones, values as JSON): --set dock_second_axis=false --set "
        "motion.unstick_s=6. For ablations: the same trials with and without a change",
    )
    parser.add_argument(
        "--trace",
        type=Path,
        default=None,
        help="write every step of every trial (true pose, command, top beliefs) to "
        "DIR/PLAN/CONDITION/trial_NNN.jsonl, to see why a trial failed",
    )
    parser.add_argument(
        "--record",
        type=Path,
        default=None,
        metavar="DIR",
        help="record every trial's task (MCAP, docs/recording.md) and keep the failed ones' "
        "in DIR/PLAN/CONDITION/trial_NNN.mcap, with DIR/PLAN.sqlite to replay them against "
        "(teachrepeat replay FILE --db DIR/PLAN.sqlite); the JSON names each file",
    )
    parser.add_argument(
        "--record-all",
        action="store_true",
        help="with --record: keep every trial's recording, not only the failed ones'",
    )
    parser.add_argument(
        "--cache",
        type=Path,
        default=DEFAULT_CACHE,
        help="keep each plan's walked tour here, per plan, seed and code "
        f"(default {DEFAULT_CACHE})",
    )
    parser.add_argument("--no-cache", action="store_true", help="walk every tour afresh")


def _trial_list(text: str) -> frozenset[int]:
    try:
        trials = frozenset(int(t) for t in text.split(",") if t.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--only takes trial numbers like 2,5,14, not {text!r}"
        ) from None
    if not trials or min(trials) < 0:
        raise argparse.ArgumentTypeError(f"--only takes trial numbers >= 0, not {text!r}")
    return trials


def navigation_env(settings: list[tuple[str, Any]]) -> dict[str, str]:
    """The servers' environment for ``--set`` (checked here first, so a typo fails fast), with
    the benchmark's own settings (:data:`server.bench.nav_sweep.BENCH_SERVER_SETTINGS`)."""
    from server.bench.nav_sweep import BENCH_SERVER_SETTINGS
    from server.navigation import NavigationParams
    from server.tuning import tuned

    overrides = {**BENCH_SERVER_SETTINGS, **dict(settings)}
    tuned(NavigationParams(), overrides)  # ValueError names what is wrong
    return {"TEACHREPEAT_NAVIGATION": json.dumps(overrides)}


def _generated_homes(args: argparse.Namespace, prog: str) -> list[tuple[Path, GeneratedHome]]:
    """``--generated K``: the homes of seeds derived from ``--seed``, written to
    ``--generated-dir`` (robot_client.sim.generate.generated_homes); exit 2 if one fails."""
    from robot_client.sim.generate import GenerateError, generated_homes

    if not args.generated:
        return []
    try:
        return generated_homes(args.generated, args.seed, args.generated_dir)
    except (GenerateError, ValueError) as exc:
        print(f"{prog}: --generated: {exc}", file=sys.stderr)
        raise SystemExit(2) from None


CAUSES_ORDER = ("wrong place", "off target", "stuck", "lost", "timeout")


def summarise(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The figures of a group of trial rows (see the module docstring)."""
    ok = [r for r in rows if r["success"]]
    failed = [r for r in rows if not r["success"]]
    lo, hi = wilson_interval(len(ok), len(rows))
    ratios = [r["path_ratio"] for r in ok if math.isfinite(r["path_ratio"])]
    causes = Counter(r["cause"] for r in failed)
    behaviours = Counter(r["final_behaviour"] or "none" for r in failed)
    return {
        "trials": len(rows),
        "successes": len(ok),
        "success_rate": len(ok) / len(rows) if rows else 0.0,
        "success_ci95": [lo, hi],
        "wrong_arrivals": sum(bool(r["wrong_arrival"]) for r in rows),
        "median_path_ratio": stats(ratios)["p50"],
        "p90_path_ratio": float(np.percentile(ratios, 90)) if ratios else math.nan,
        "median_time_s": stats([r["time_s"] for r in ok])["p50"],
        "median_free_space_ratio": stats([r["free_space_ratio"] for r in ok])["p50"],
        "explore_fraction": float(np.mean([r["explore_fraction"] for r in rows])) if rows else 0.0,
        "failures_by_cause": {c: causes[c] for c in CAUSES_ORDER if causes[c]},
        "failures_by_behaviour": dict(sorted(behaviours.items())),
        **localisation_summary(rows),
        "tracking_error_m": tracking_summary(rows),
        "behaviour_share": behaviour_share(rows),
    }


def tracking_summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The tracking error while following a taught path by the pose relative to it (metres
    from the simulator's true position to that edge's true taught path), over every such
    frame of ``rows``: ``p50``, ``p90`` and how many frames."""
    errors = [e for r in rows for e in r.get("tracking_error_m") or ()]
    if not errors:
        return {"p50": None, "p90": None, "frames": 0}
    a = np.asarray(errors, dtype=np.float64)
    return {
        "p50": float(np.percentile(a, 50)),
        "p90": float(np.percentile(a, 90)),
        "frames": len(errors),
    }


def behaviour_share(rows: list[dict[str, Any]]) -> dict[str, float]:
    """The share of all frames of ``rows`` each behaviour drove the robot (following,
    searching, exploring, retracing, ...), largest first."""
    counts: Counter[str] = Counter()
    for r in rows:
        counts.update(r.get("behaviours") or {})
    total = sum(counts.values())
    if not total:
        return {}
    return {k: round(v / total, 4) for k, v in counts.most_common()}


def _line(label: str, s: dict[str, Any]) -> str:
    lo, hi = s["success_ci95"]
    causes = ", ".join(f"{k} {v}" for k, v in s["failures_by_cause"].items()) or "-"
    return (
        f"{label:<28} {s['successes']:>3}/{s['trials']:<3} {s['success_rate']:>5.0%} "
        f"[{lo:4.0%}, {hi:4.0%}]  {s['wrong_arrivals']:>5}  "
        f"{s['median_path_ratio']:4.2f} / {s['p90_path_ratio']:4.2f}  "
        f"{s['median_time_s']:6.0f} s  {causes}"
    )


def _localisation_line(label: str, s: dict[str, Any]) -> str:
    first = s["median_first_correct_s"]
    text = (
        f"{label:<28} first right 'localised' p50 "
        f"{'-' if first is None else f'{first:.1f} s'} (never {s['never_correct']}), wrong "
        f"claims {s['wrong_claims']} in {s['trials_with_wrong_claims']} trials"
    )
    track = s.get("tracking_error_m") or {}
    if track.get("frames"):
        text += f", tracking error p50 {track['p50']:.2f} m p90 {track['p90']:.2f} m"
    share = s.get("behaviour_share") or {}
    if share:
        text += "; frames: " + ", ".join(f"{k} {v:.0%}" for k, v in list(share.items())[:5])
    return text


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from robot_client.sim.check_plan import load_plans_or_exit
    from server.bench.nav_sweep import (
        SweepConfig,
        TrialError,
        TrialSpec,
        group_rows,
        prepare_recordings,
        run_trials,
    )

    prog = "teachrepeat bench navigate"
    if args.trials < 1 or args.workers < 1 or args.max_steps < 1:
        print(f"{prog}: --trials, --workers and --max-steps must be at least 1", file=sys.stderr)
        return 2
    if args.record_all and args.record is None:
        print(f"{prog}: --record-all needs --record DIR (where to keep them)", file=sys.stderr)
        return 2
    try:
        env = navigation_env(args.settings)
    except ValueError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
    generated = _generated_homes(args, prog)
    plan_files = [*(args.plan or []), *(path for path, _ in generated)]
    plans = load_plans_or_exit(plan_files or [None], prog)
    conditions = list(dict.fromkeys(args.condition))
    trials = [t for t in range(args.trials) if args.only is None or t in args.only]
    specs = [TrialSpec(p, c, t) for p in range(len(plans)) for c in conditions for t in trials]
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="teachrepeat-bench-") as scratch:
        recordings = prepare_recordings(
            [plan.source for plan in plans],
            [plan.sha256 for plan in plans],
            args.seed,
            None if args.no_cache else args.cache,
            Path(scratch),
            workers=args.workers,
        )
        walk_s = time.perf_counter() - t0
        config = SweepConfig(
            plans=tuple(plan.source for plan in plans),
            recordings=tuple(recordings),
            seed=args.seed,
            max_steps=args.max_steps,
            env=tuple(env.items()),
            trace=None if args.trace is None else str(args.trace),
            record=None if args.record is None else str(args.record.resolve()),
            record_all=args.record_all,
            no_depth=args.no_depth,
        )
        bar = tqdm(total=len(specs), desc="trials", unit="trial")

        def show(r: dict[str, Any]) -> None:
            bar.update(1)
            verdict = "ok" if r["success"] else r["cause"]
            tqdm.write(
                f"{r['plan']:<12} {r['condition']:<8} {r['trial']:3d} -> {r['goal']:<14} "
                f"{verdict:<11} {r['distance_m']:5.2f} m {r['time_s']:5.0f} s (robot)  "
                f"ratio {r['path_ratio']:4.2f}  {r['reason'] or ''}"
            )

        def report(e: TrialError) -> None:
            bar.update(1)
            name = plans[e.spec.plan].name
            tqdm.write(f"{name:<12} {e.spec.condition:<8} {e.spec.trial:3d} raised:\n{e.traceback}")

        with bar:
            rows, teach_s, errors = run_trials(
                config, specs, workers=args.workers, on_row=show, on_error=report
            )
    if errors and not rows:
        print(f"{prog}: every trial raised (tracebacks above); nothing to report", file=sys.stderr)
        return 1
    wall_s = time.perf_counter() - t0
    results = []
    for (index, condition), group in group_rows(rows, ("plan_index", "condition")):
        plan = plans[index]
        results.append(
            {
                "plan": plan.name,
                "plan_file": Path(plan.source).name,
                "plan_sha256": plan.sha256,
                "condition": condition,
                **summarise(group),
                "rows": group,
            }
        )
    pooled = summarise(rows)
    header = (
        f"{'plan / condition':<28} {'success':>7} {'':5} {'95% interval':<12}  {'wrong':>5}  "
        f"path ratio p50/p90  {'time p50':>8}  failures by cause"
    )
    print(header)
    for r in results:
        print(_line(f"{r['plan']} / {r['condition']}", r))
    if len(results) > 1:
        print(_line("pooled", pooled))
    labelled = [(f"{r['plan']} / {r['condition']}", r) for r in results]
    for label, figures in labelled + ([("pooled", pooled)] if len(results) > 1 else []):
        print(_localisation_line(label, figures))
    print(
        f"{len(rows)} trials in {wall_s / 60:.1f} min on {args.workers} worker(s) "
        f"(walking tours {walk_s:.0f} s, teaching servers {teach_s:.0f} s); time = robot seconds"
    )
    kept = [r for r in rows if r.get("recording")]
    if args.record is not None:
        which = "trial" if args.record_all else "failed trial"
        print(f"recordings of {len(kept)} {which}s kept in {args.record}")
        if kept:
            first = kept[0]
            print(
                f"replay one: teachrepeat replay {first['recording']} --db {first['recording_db']}"
            )
    summary: dict[str, Any] = {
        "plans": [{"file": Path(p.source).name, "name": p.name, "sha256": p.sha256} for p in plans],
        "conditions": conditions,
        "seed": args.seed,
        "trials_per_group": len(trials),
        "only": None if args.only is None else sorted(args.only),
        "max_steps": args.max_steps,
        "no_depth": args.no_depth,
        "settings": dict(args.settings),
        "bench_server_settings": json.loads(env["TEACHREPEAT_NAVIGATION"]),
        "workers": args.workers,
        "record": None
        if args.record is None
        else {"folder": str(args.record), "all": args.record_all, "kept": len(kept)},
        "wall_s": wall_s,
        "walk_tours_s": walk_s,
        "teach_servers_s": teach_s,
        "time_unit": "time_s and median_time_s are robot (simulated) seconds",
        "path_ratio_definition": "driven metres / shortest taught route (free space to a place, "
        "then taught edges by their taught lengths); free_space_ratio: / A* path on the plan",
        "success_definition": "said 'arrived' within 0.5 m of the goal place",
        "causes": "wrong place: arrived nearer another place; off target: arrived at the goal "
        "but > 0.5 m off; stuck: stayed within 0.25 m through the last 20 s while driving; "
        "lost: the belief not localised on half of the last 20 s; timeout: the rest",
        "pooled": pooled,
    }
    if errors:
        summary["errors"] = [{"plan": plans[e.spec.plan].name, **e.row()} for e in errors]
    if generated:
        summary["generated"] = [
            {"seed": home.seed, "file": str(path), "name": home.data["name"], "sha256": home.sha256}
            for path, home in generated
        ]
    if len(results) == 1:
        only = results[0]
        summary.update({k: v for k, v in only.items() if k != "rows"})
        summary["rows"] = only["rows"]
    else:
        summary["results"] = results
    write_json(args.json, summary)
    if errors:
        print(
            f'{prog}: {len(errors)} trial(s) raised (above; the JSON\'s "errors"); the '
            f"figures are of the {len(rows)} that finished",
            file=sys.stderr,
        )
        return 1
    return 0
