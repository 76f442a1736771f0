"""``python -m server.bench.nav_table RESULT.json [BEFORE.json]``: the figures of a
``bench navigate`` run as Markdown tables (per home and condition, pooled, failures by cause and
by the behaviour at the end), and trial by trial what changed against an earlier run of the
same plans, seed and trials."""

from __future__ import annotations

import json
import sys
from collections import Counter
from pathlib import Path
from typing import Any


def groups(result: dict[str, Any]) -> list[dict[str, Any]]:
    return result.get("results") or [result]


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
    def rows(r: dict[str, Any]) -> dict[tuple[str, str, int], dict[str, Any]]:
        return {(x["plan"], x["condition"], x["trial"]): x for g in groups(r) for x in g["rows"]}

    a, b = rows(before), rows(after)
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


def main(argv: list[str] | None = None) -> None:
    args = sys.argv[1:] if argv is None else argv
    result = json.loads(Path(args[0]).read_text())
    print(table(result))
    if len(args) > 1:
        print()
        print(changes(json.loads(Path(args[1]).read_text()), result))


if __name__ == "__main__":
    main()
