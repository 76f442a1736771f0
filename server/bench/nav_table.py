"""``python -m server.bench.nav_table RESULT.json [BEFORE.json]``: the figures of a
``bench navigate`` run as Markdown tables (per home and condition, pooled, failures by cause and
by the behaviour at the end), and trial by trial what changed against an earlier run of the
same plans, seed and trials.

``python -m server.bench.nav_table --pairs AFTER.json:BEFORE.json [AFTER.json:BEFORE.json ...]``:
a change measured on several seeds, each run against the code before it on the same trials:
per pair and pooled, arrivals and wrong arrivals before and after, the trials fixed and
broken, and how often a split of fixed and broken at least that uneven comes by chance (the
exact two-sided sign test on the trials whose outcome changed); the same for wrong arrivals:
trials wrong before only (``wrong_gone``) and after only (``wrong_new``), with their sign
test. A change moves 30-60 of 72 trials onto another course, so one seed's difference says
little (docs/navigation.md 3.1)."""

from __future__ import annotations

import json
import math
import sys
from collections import Counter
from pathlib import Path
from typing import Any


def groups(result: dict[str, Any]) -> list[dict[str, Any]]:
    return result.get("results") or [result]


def trial_rows(result: dict[str, Any]) -> dict[tuple[str, str, int], dict[str, Any]]:
    """A run's trials by (plan, condition, trial number)."""
    return {(x["plan"], x["condition"], x["trial"]): x for g in groups(result) for x in g["rows"]}


def table(result: dict[str, Any]) -> str:
    out = [
        "| home | condition | success | 95 % interval | wrong | path ratio p50 / p90 | "
        "time p50 (robot s) | failures by cause | failures by final behaviour |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for g in [*groups(result), {**result["pooled"], "plan": "**pooled**", "condition": ""}]:
        lo, hi = g["success_ci95"]
        causes = ", ".join(f"{k} {v}" for k, v in g["failures_by_cause"].items()) or "-"
        behaviours = ", ".join(f"{k} {v}" for k, v in g["failures_by_behaviour"].items()) or "-"
        out.append(
            f"| {g['plan']} | {g['condition']} | {g['successes']}/{g['trials']} = "
            f"{g['success_rate']:.0%} | {lo:.0%}-{hi:.0%} | {g['wrong_arrivals']} | "
            f"{g['median_path_ratio']:.2f} / {g['p90_path_ratio']:.2f} | "
            f"{g['median_time_s']:.0f} | {causes} | {behaviours} |"
        )
    return "\n".join(out)


def changes(before: dict[str, Any], after: dict[str, Any]) -> str:
    a, b = trial_rows(before), trial_rows(after)
    moved: Counter[str] = Counter()
    lines = []
    for key in sorted(a.keys() & b.keys()):
        x, y = a[key], b[key]
        if x["success"] != y["success"]:
            moved["fixed" if y["success"] else "broken"] += 1
            lines.append(
                f"* {key[0]} / {key[1]} trial {key[2]} -> {x['goal']}: "
                f"{'ok' if x['success'] else x['cause']} -> {'ok' if y['success'] else y['cause']}"
            )
        elif abs(x["time_s"] - y["time_s"]) > 1e-6:
            moved["same outcome, another course"] += 1
        else:
            moved["identical"] += 1
    head = ", ".join(f"{k} {v}" for k, v in sorted(moved.items()))
    return f"{len(a.keys() & b.keys())} trials in both: {head}\n\n" + "\n".join(lines)


def sign_test(fixed: int, broken: int) -> float:
    """Two-sided exact sign test: the chance, with fixed and broken equally likely for each
    changed trial, of a split at least as uneven as ``fixed`` against ``broken`` (1 when
    none changed)."""
    if fixed < 0 or broken < 0:
        raise ValueError("counts must be >= 0")
    n = fixed + broken
    if n == 0:
        return 1.0
    k = min(fixed, broken)
    tail = sum(math.comb(n, i) for i in range(k + 1)) / 2**n
    return min(1.0, 2.0 * tail)


def paired(before: dict[str, Any], after: dict[str, Any]) -> dict[str, int]:
    """Arrivals and wrong arrivals of two runs of the same trials, the trials in both that
    arrived in one only (``fixed``: after only; ``broken``: before only) and those that went to
    a wrong place in one only (``wrong_gone``: before only; ``wrong_new``: after only)."""

    a, b = trial_rows(before), trial_rows(after)
    both = a.keys() & b.keys()
    if not both:
        raise ValueError("the two runs share no trials: not the same plans, seed and trials")
    # the flag ``bench navigate`` counts its wrong arrivals by
    wa = {k: bool(a[k]["wrong_arrival"]) for k in both}
    wb = {k: bool(b[k]["wrong_arrival"]) for k in both}
    return {
        "trials": len(both),
        "before": sum(bool(a[k]["success"]) for k in both),
        "after": sum(bool(b[k]["success"]) for k in both),
        "wrong_before": sum(wa.values()),
        "wrong_after": sum(wb.values()),
        "fixed": sum(bool(b[k]["success"]) and not a[k]["success"] for k in both),
        "broken": sum(bool(a[k]["success"]) and not b[k]["success"] for k in both),
        "wrong_gone": sum(wa[k] and not wb[k] for k in both),
        "wrong_new": sum(wb[k] and not wa[k] for k in both),
    }


def pairs_table(named: list[tuple[str, dict[str, int]]]) -> str:
    """Markdown: one row per ``(name, paired(...))`` and the pooled row, with the sign test."""
    out = [
        "| pair | trials | arrived after / before | wrong after / before | fixed | broken | "
        "sign test p | wrong gone | wrong new | sign test p (wrong) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    if not named:
        raise ValueError("no pairs: give at least one AFTER.json:BEFORE.json")
    total = {k: sum(c[k] for _, c in named) for k in named[0][1]}
    for name, c in [*named, ("**pooled**", total)]:
        out.append(
            f"| {name} | {c['trials']} | {c['after']} / {c['before']} | "
            f"{c['wrong_after']} / {c['wrong_before']} | {c['fixed']} | {c['broken']} | "
            f"{sign_test(c['fixed'], c['broken']):.2f} | {c['wrong_gone']} | {c['wrong_new']} | "
            f"{sign_test(c['wrong_gone'], c['wrong_new']):.2f} |"
        )
    return "\n".join(out)


def main(argv: list[str] | None = None) -> None:
    args = sys.argv[1:] if argv is None else argv
    if not args or args == ["--pairs"]:
        raise SystemExit(
            "usage: nav_table RESULT.json [BEFORE.json] | "
            "nav_table --pairs AFTER.json:BEFORE.json [AFTER.json:BEFORE.json ...]"
        )
    if args[0] == "--pairs":
        named = []
        for pair in args[1:]:
            after, sep, before = pair.partition(":")
            if not sep:
                raise SystemExit(f"--pairs takes AFTER.json:BEFORE.json, got {pair!r}")
            runs = [json.loads(Path(f).read_text()) for f in (before, after)]
            named.append((f"{Path(after).stem} / {Path(before).stem}", paired(*runs)))
        print(pairs_table(named))
        return
    result = json.loads(Path(args[0]).read_text())
    print(table(result))
    if len(args) > 1:
        print()
        print(changes(json.loads(Path(args[1]).read_text()), result))


if __name__ == "__main__":
    main()
