"""``python -m server.bench.localize_table [--halves] A.json [B.json ...]``: the figures of
``bench localize`` runs as one Markdown table, a row per data set x half x direction x weights x
tolerance (0, 2, 10) and a column per method (ir_only, tracker, smoother); ``--halves`` adds the
first and second half scored inside each full run (``halves`` in the JSON).

The data set is named after the folder holding both traversals (``nordland/summer`` and
``nordland/winter`` -> ``nordland``), the direction is ``query -> reference``. A cell is recall@1;
the first row of a block also gives the mean error in frames (it does not depend on the
tolerance). Results written before ``directions`` existed give their forward run, its recall read
from ``recall_curve``.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from pathlib import Path, PurePath
from typing import Any

#: tolerances (frames) of the table
TOLERANCES = ("0", "2", "10")
METHODS = ("ir_only", "tracker", "smoother")
#: signature blocks of results that do not name them
DEFAULT_BLOCKS = ("hist", "thumb", "desc_mean", "desc_var", "patch")


def dataset_name(reference: str, query: str) -> str:
    """The folder holding both traversals, else both folder names."""
    ref, qry = PurePath(reference), PurePath(query)
    if ref.parent == qry.parent and ref.parent.name:
        return ref.parent.name
    return f"{ref.name} / {qry.name}"


def directions(result: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The per-direction summaries of a result (``directions``; an older result: its forward
    run, recall at each tolerance taken from ``recall_curve``)."""
    if "directions" in result:
        return dict(result["directions"])
    curve = result["recall_curve"]
    at: dict[str, dict[str, dict[str, float]]] = {}
    for t in TOLERANCES:
        if int(t) in curve["tolerance"]:
            k = curve["tolerance"].index(int(t))
            at[t] = {
                m: {"recall@1": curve[m][k], "mean_error_frames": result[m]["mean_error_frames"]}
                for m in METHODS
            }
    forward = {key: result[key] for key in ("reference", "query", "frames", "weights")}
    forward.update(recall_at=at, weights_used=result.get("weights_used", []))
    return {"forward": forward}


def weights_cell(d: dict[str, Any]) -> str:
    """``learned: 0.64/0.03/0.00/0.00/0.34`` (the weights used, in block order)."""
    used = "/".join(f"{w:.2f}" for w in d.get("weights_used", []))
    return f"{d['weights']}: {used}" if used else str(d["weights"])


def blocks_of(result: dict[str, Any], *, halves: bool) -> list[tuple[str, dict[str, Any]]]:
    """``(half label, direction summary)`` per direction of a result; with ``halves`` also
    each half scored inside a full run (labelled ``first of all`` / ``second of all``)."""
    out = []
    half = result.get("half", "all")
    for d in directions(result).values():
        out.append((half, d))
        if halves:
            for name, h in d.get("halves", {}).items():
                out.append((f"{name} of {half}", {**d, **h}))
    return out


def rows(result: dict[str, Any], *, halves: bool = False) -> list[str]:
    """The table rows of one result file (a block of one row per tolerance per direction)."""
    out = []
    for half, d in blocks_of(result, halves=halves):
        name = dataset_name(d["reference"], d["query"])
        direction = f"{PurePath(d['query']).name} -> {PurePath(d['reference']).name}"
        first = True
        for t in TOLERANCES:
            scores = d["recall_at"].get(t)
            if scores is None:
                continue
            cells = []
            for m in METHODS:
                s = scores[m]
                cell = f"{s['recall@1']:.3f}"
                if first:
                    cell += f" ({s['mean_error_frames']:.2f})"
                cells.append(cell)
            head = (
                [name, half, direction, weights_cell(d), str(d["frames"])]
                if first
                else ["", "", "", "", ""]
            )
            out.append("| " + " | ".join([*head, t, *cells]) + " |")
            first = False
    return out


def table(results: Sequence[dict[str, Any]], *, halves: bool = False) -> str:
    """One Markdown table of every direction of every result (with ``halves``, also the halves
    scored inside full runs)."""
    blocks = next(
        (
            d["weight_blocks"]
            for r in results
            for d in directions(r).values()
            if "weight_blocks" in d
        ),
        DEFAULT_BLOCKS,
    )
    out = [
        f"| data | half | query -> reference | weights ({'/'.join(blocks)}) | frames | tol | "
        + " | ".join(METHODS)
        + " |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for result in results:
        out.extend(rows(result, halves=halves))
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    """Print the table of the result files named on the command line (``--halves``: also the
    halves of full runs); 2 without any."""
    args = sys.argv[1:] if argv is None else argv
    halves = "--halves" in args
    files = [a for a in args if a != "--halves"]
    if not files:
        print("usage: python -m server.bench.localize_table [--halves] RESULT.json [...]")
        return 2
    print(table([json.loads(Path(a).read_text()) for a in files], halves=halves))
    print()
    print("recall@1 at each tolerance (frames); first row of a block: (mean error in frames)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
