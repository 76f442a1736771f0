"""``python -m server.bench.nav_traces TRACE_DIR RESULT.json [--json OUT]``: what the path
tracker's locks did in a traced ``bench navigate`` run (``--trace TRACE_DIR --json
RESULT.json``), judged by the simulator's truth that the trace carries (each frame's distance
from the tracked edge's taught path, ``path.true_error``):

* locks let go: on the path (within :data:`ON_PATH_M`), off it (beyond :data:`OFF_PATH_M`) or
  between, by why (:func:`why_let_go`), and the frames and behaviours until the next lock;
  for those let go for want of measurements, on the path against off it, the medians of what
  the lock's last frame held (:data:`LET_GO_SIGNS`);
* locks taken: where, whether the robot was turning at a place searching for the edge then
  (RotateAndFindEdge, the estimate within :data:`AT_PLACE_M` of the edge's start), and how
  many of each in trials that failed; in traces that carry it, also by where the robot was
  against the path and against where the estimate put it (``path.estimate_error``, on, near
  or off by the same bounds: an estimate on the path's line metres from the robot is "path
  on / estimate off");
* every false arrival (the task said "arrived" away from the goal): the tracker's state at
  the end;
* with ``--plan`` (the run's plan files, for where their places were taught): how often the
  belief's most likely state is a place while the robot turns on the spot and while it
  drives, within :data:`NEAR_PLACE_M` of a place and further (:func:`turning`), and how far
  from the place it searched at the robot stood when it took a lock searching there.

The figures of docs/navigation.md section 4 that count locks come from this command."""

from __future__ import annotations

import argparse
import json
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from server.bench.nav_sweep import slug
from server.bench.nav_table import groups
from server.navigation.pathtrack import TopometricParams

ON_PATH_M = 0.3
"""A lock within this of the tracked edge's taught path (true pose) is on the path, m."""
OFF_PATH_M = 0.6
"""A lock further than this from the tracked edge's taught path is off it, m."""
AT_PLACE_M = 0.3
"""A lock taken while searching within this of the edge's start counts as at the place, m."""
NEAR_PLACE_M = 1.5
"""A robot within this of a place's taught spot (true pose) is near a place, m."""
TURN_V = 0.02
TURN_W = 0.2
DRIVE_V = 0.05
"""A frame whose command drives at most ``TURN_V`` m/s and turns at least ``TURN_W`` rad/s
turns on the spot; one driving faster than ``DRIVE_V`` m/s drives."""
SEARCH_FROM_M = (1.0, 2.0)
"""The bounds (m) by which :func:`summary` counts locks taken searching at a place, by the
robot's true distance from that place's taught spot."""

Spots = dict[str, dict[str, tuple[float, float]]]
"""Plan name -> place name -> where the place was taught (x, y; m)."""


@dataclass(frozen=True)
class Trial:
    """One traced trial: its key (home, condition, trial), outcome and frames."""

    plan: str
    condition: str
    trial: int
    success: bool
    state: str
    distance_m: float
    rows: list[dict[str, Any]]


def where(error: float | None) -> str:
    """``"on"``, ``"off"`` or ``"near"`` the path for a true distance from it (m)."""
    if error is None:
        return "near"
    if error <= ON_PATH_M:
        return "on"
    return "off" if error > OFF_PATH_M else "near"


def locked(row: dict[str, Any]) -> bool:
    path = row["path"]
    return bool(path and path["locked"])


def why_let_go(before: dict[str, Any], after: dict[str, Any], p: TopometricParams) -> str:
    """Why the lock of frame ``before`` is gone at frame ``after``: ``"no edge"`` (nothing
    tracked), ``"another edge"``, ``"uncertain"`` (a standard deviation beyond the lock's
    bounds: grown, or a fresh start), or ``"measurements"`` (within the bounds: no heading
    measured for ``lock_fix_s``, or too few since the estimate moved)."""
    path = after["path"]
    if path is None:
        return "no edge"
    if path["edge"] != before["path"]["edge"]:
        return "another edge"
    _, lateral, heading = path["sd"]
    if lateral > p.lock_lateral_m or heading > p.lock_heading_rad:
        return "uncertain"
    return "measurements"


def let_go(trial: Trial, p: TopometricParams) -> list[dict[str, Any]]:
    """Every lock let go in ``trial``: where the robot was, why, and until the next lock (on
    any edge) the frames (``None``: never again) and the behaviours that ran."""
    rows, out = trial.rows, []
    for i in range(len(rows) - 1):
        if not locked(rows[i]) or locked(rows[i + 1]):
            continue
        j = i + 1
        while j < len(rows) and not locked(rows[j]):
            j += 1
        behaviours = Counter(r["behaviour"] for r in rows[i + 1 : j])
        path = rows[i]["path"]
        k = i  # the first frame of this lock
        while k > 0 and locked(rows[k - 1]) and rows[k - 1]["path"]["edge"] == path["edge"]:
            k -= 1
        name, mass = rows[i]["top"][0] if rows[i].get("top") else ("", 0.0)
        out.append(
            {
                "step": rows[i]["step"],
                "where": where(path["true_error"]),
                "why": why_let_go(rows[i], rows[i + 1], p),
                "frames": j - i - 1 if j < len(rows) else None,
                "behaviours": dict(behaviours),
                "locked_frames": i - k + 1,
                "lateral_m": abs(path["lateral"]),
                "sd_along_m": path["sd"][0],
                "gained_m": path["along"] - rows[k]["path"]["along"],
                "belief_on_an_edge": mass if "->" in name else 0.0,
            }
        )
    return out


LET_GO_SIGNS = ("locked_frames", "lateral_m", "sd_along_m", "gained_m", "belief_on_an_edge")
"""What :func:`let_go` records of a lock's last frame, whose medians :func:`summary` compares
between locks let go on the path and off it for want of measurements."""


def top_state(row: dict[str, Any]) -> str:
    """The name of the state the frame's belief holds most likely ("" when it names none)."""
    top = row.get("top") or [("", 0.0)]
    return str(top[0][0])


def place_distance(row: dict[str, Any], spots: dict[str, tuple[float, float]]) -> float | None:
    """Metres from the frame's true pose to the taught spot of the place the belief holds
    most likely, or ``None`` when that is not a place of ``spots``."""
    spot = spots.get(top_state(row))
    if spot is None:
        return None
    return float(np.hypot(row["pose"][0] - spot[0], row["pose"][1] - spot[1]))


def taken(
    trial: Trial, spots: dict[str, tuple[float, float]] | None = None
) -> list[dict[str, Any]]:
    """Every lock taken in ``trial`` (a locked frame after one not locked, or locked on
    another edge): where, whether the robot was searching at a place and, with the plan's
    place ``spots``, how far from the one searched at (the belief's most likely place; m)."""
    rows, out = trial.rows, []
    for i in range(1, len(rows)):
        now, last = rows[i], rows[i - 1]
        if not locked(now) or (locked(last) and last["path"]["edge"] == now["path"]["edge"]):
            continue
        searching = last["action"] == "rotate_and_find_edge" and now["path"]["along"] < AT_PLACE_M
        out.append(
            {
                "step": now["step"],
                "where": where(now["path"]["true_error"]),
                "searching": searching,
                "failed_trial": not trial.success,
                "place_m": None if not searching or spots is None else place_distance(now, spots),
                "estimate": None
                if (missed := now["path"].get("estimate_error")) is None
                else where(missed),
            }
        )
    return out


def turning(trial: Trial, spots: dict[str, tuple[float, float]]) -> Counter[tuple[str, str, bool]]:
    """Frames of ``trial`` counted by motion (``"turning"`` on the spot or ``"driving"``, by the
    command), ``"near"`` a place (within :data:`NEAR_PLACE_M` of one's taught spot, true pose)
    or ``"far"``, and whether the belief's most likely state was a place then."""
    out: Counter[tuple[str, str, bool]] = Counter()
    xy = np.array(list(spots.values()), dtype=np.float64).reshape(-1, 2)
    if not len(xy):
        return out
    for row in trial.rows:
        v, w = abs(row["v"]), abs(row["w"])
        motion = "turning" if v <= TURN_V and w >= TURN_W else "driving" if v > DRIVE_V else None
        if motion is None:
            continue
        near = np.min(np.hypot(*(xy - np.asarray(row["pose"][:2])).T)) <= NEAR_PLACE_M
        out[(motion, "near" if near else "far", top_state(row) in spots)] += 1
    return out


def read_spots(plans: list[Path]) -> Spots:
    """Where each plan's places were taught, by plan name (the plan files' ``name`` and
    ``places``)."""
    out: Spots = {}
    for file in plans:
        plan = json.loads(file.read_text())
        out[plan["name"]] = {p["name"]: (float(p["x"]), float(p["y"])) for p in plan["places"]}
    return out


def _by_place(trials: list[Trial], took: list[dict[str, Any]], spots: Spots) -> dict[str, Any]:
    """The counts :func:`summary` adds with the plans' place ``spots``, from the ``trials``
    and the locks taken in them (:func:`taken`, given the spots)."""
    frames: Counter[tuple[str, str, bool]] = Counter()
    for t in trials:
        frames += turning(t, spots.get(t.plan, {}))
    belief = {
        f"{motion}, {near}": {
            "frames": (n := frames[(motion, near, True)] + frames[(motion, near, False)]),
            "belief_top_a_place": round(frames[(motion, near, True)] / n, 3) if n else None,
        }
        for motion in ("turning", "driving")
        for near in ("near", "far")
    }
    lo, hi = SEARCH_FROM_M
    bins: Counter[str] = Counter()
    failed: Counter[str] = Counter()
    for x in took:
        d = x["place_m"]
        if d is None:
            continue
        key = f"< {lo} m" if d < lo else f"{lo}-{hi} m" if d < hi else f">= {hi} m"
        bins[key] += 1
        failed[key] += x["failed_trial"]
    return {
        "near_place_m": NEAR_PLACE_M,
        "belief_while": belief,
        "locks_taken_searching_by_distance_from_the_place": {
            k: {"all": bins[k], "in failed trials": failed[k]}
            for k in (f"< {lo} m", f"{lo}-{hi} m", f">= {hi} m")
        },
    }


def false_arrival(trial: Trial) -> dict[str, Any] | None:
    """The tracker's state where ``trial`` said "arrived" away from the goal, else ``None``."""
    if trial.state != "arrived" or trial.success or not trial.rows:
        return None
    k = len(trial.rows) - 1
    while k > 0 and trial.rows[k]["behaviour"] == "stand":
        k -= 1
    row = trial.rows[k]
    path = row["path"]
    return {
        "trial": f"{trial.plan} / {trial.condition} / {trial.trial}",
        "distance_m": round(trial.distance_m, 2),
        "behaviour": row["behaviour"],
        "reason": row["reason"],
        "locked": bool(path and path["locked"]),
        "along_m": None if path is None else path["along"],
        "sd_along_m": None if path is None else path["sd"][0],
        "true_error_m": None if path is None else path["true_error"],
    }


def load(trace_dir: Path, result: dict[str, Any]) -> list[Trial]:
    """The traced trials of a ``bench navigate`` result (those with a trace file)."""
    trials = []
    for group in groups(result):
        for row in group["rows"]:
            file = (
                trace_dir / slug(row["plan"]) / row["condition"] / f"trial_{row['trial']:03d}.jsonl"
            )
            if not file.exists():
                continue
            frames = [json.loads(line) for line in file.read_text().splitlines() if line]
            trials.append(
                Trial(
                    row["plan"],
                    row["condition"],
                    row["trial"],
                    bool(row["success"]),
                    row["state"],
                    float(row["distance_m"]),
                    frames,
                )
            )
    return trials


def summary(
    trials: list[Trial], p: TopometricParams | None = None, spots: Spots | None = None
) -> dict[str, Any]:
    """The counts this command prints, as a dictionary (its ``--json``); ``p``: the lock's
    bounds (the defaults when ``None``); ``spots`` (:func:`read_spots`): also the belief while
    turning and the locks taken searching by the distance from the place (``by_place``)."""
    p = TopometricParams() if p is None else p
    gone = [x for t in trials for x in let_go(t, p)]
    took = [x for t in trials for x in taken(t, None if spots is None else spots.get(t.plan, {}))]
    took_all = Counter((x["where"], x["searching"]) for x in took)
    took_failed = Counter((x["where"], x["searching"]) for x in took if x["failed_trial"])
    again: Counter[str] = Counter()
    for x in gone:
        if x["where"] == "on":
            again.update(x["behaviours"])
    out = {
        "trials": len(trials),
        "on_path_m": ON_PATH_M,
        "off_path_m": OFF_PATH_M,
        "let_go": {
            f"{w} / {why}": n
            for (w, why), n in sorted(Counter((x["where"], x["why"]) for x in gone).items())
        },
        "frames_to_lock_again_after_on_path": sum(
            x["frames"] for x in gone if x["where"] == "on" and x["frames"] is not None
        ),
        "behaviours_until_locked_again_after_on_path": dict(again.most_common()),
        "let_go_for_measurements_medians": {
            w: {sign: round(float(np.median([x[sign] for x in group])), 3) for sign in LET_GO_SIGNS}
            for w in ("on", "off")
            if (group := [x for x in gone if (x["where"], x["why"]) == (w, "measurements")])
        },
        "taken": {
            f"{w} / {'searching at a place' if s else 'otherwise'}": {
                "all": n,
                "in failed trials": took_failed[(w, s)],
            }
            for (w, s), n in sorted(took_all.items())
        },
        "false_arrivals": [a for t in trials if (a := false_arrival(t)) is not None],
    }
    judged = [x for x in took if x["estimate"] is not None]
    if judged:  # traces written since the estimate's own error was recorded
        both = Counter((x["where"], x["estimate"]) for x in judged)
        lost = Counter((x["where"], x["estimate"]) for x in judged if x["failed_trial"])
        out["taken_by_estimate_error"] = {
            f"path {w} / estimate {e}": {"all": n, "in failed trials": lost[(w, e)]}
            for (w, e), n in sorted(both.items())
        }
    if spots is not None:
        out["by_place"] = _by_place(trials, took, spots)
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m server.bench.nav_traces", description=__doc__)
    ap.add_argument("trace_dir", type=Path, help="the --trace folder of a bench navigate run")
    ap.add_argument("result", type=Path, help="the --json file of the same run")
    ap.add_argument("--json", type=Path, default=None, help="also write the counts here")
    ap.add_argument(
        "--plan",
        type=Path,
        nargs="+",
        default=None,
        help="the run's plan files: also count the belief while turning and the locks taken "
        "searching by the robot's distance from the place (its true pose)",
    )
    args = ap.parse_args(argv)
    trials = load(args.trace_dir, json.loads(args.result.read_text()))
    if not trials:
        ap.error(f"no trace of any trial of {args.result} under {args.trace_dir}")
    spots = None
    if args.plan is not None:
        try:
            spots = read_spots(args.plan)
        except (OSError, ValueError, KeyError, TypeError) as exc:
            ap.error(f"--plan: cannot read the places of {args.plan}: {exc}")
        unknown = sorted({t.plan for t in trials} - set(spots))
        if unknown:
            ap.error(f"--plan: no plan named {', '.join(unknown)}; pass the run's plan files")
    out = summary(trials, spots=spots)
    print(json.dumps(out, indent=2))
    if args.json is not None:
        args.json.write_text(json.dumps(out, indent=2) + "\n")


if __name__ == "__main__":
    main()
