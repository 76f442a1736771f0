"""Where a server's CPU goes, by stage of a frame: a sampling profile of the real process.

``teachrepeat bench load --profile`` runs `py-spy <https://github.com/benfred/py-spy>`_ against
the server process for the measured window (``py-spy record --format raw``: every sample is a
Python stack of a thread that was running, counted; the server is neither changed nor slowed
by instrumentation, py-spy reads its memory from outside). :func:`stage_of` names the stage a
stack belongs to and :func:`stage_profile` adds the samples up per stage:

* ``decode``: the JPEG decoded into pixels (``decode_jpeg``);
* ``features``: corners, descriptors and the signature of the frame (``extract``);
* ``retrieval``: the frame against the tour's images (``TourRuntime.observe``);
* ``belief``: the tracker's predict and update (``Tracker.step``, the smoother);
* ``policy``: the votes and the action (``decide``);
* ``homing``: the frame matched against the taught images the behaviours ask for, with the zoom
  levels of a docking step (``match_views``; since the matches are made when a behaviour
  reads them, ``LazyFits.__getitem__`` inside the behaviour);
* ``motion``: behaviours, arbitration, docking, the task (the rest of ``Navigator.step``);
* ``encode``: the answer built and serialised, observers told (``frame_result``, pydantic);
* ``persist``: the task and belief snapshot written to the database;
* ``http``: everything else of the process: uvicorn, Starlette, FastAPI, routing, validation,
  the event loop (uvloop's C code shows as ``Runner.run``), background work.

py-spy leaves out threads the kernel says are asleep, but a thread queued for a lock or for the
GIL still shows, in the Python line it stopped at. Stacks whose leaf is a wait
(:data:`WAITS`: ``Condition.wait``, ``Semaphore.acquire``, ...) are counted as ``waiting`` and
left out of the stages; a wait for the GIL elsewhere cannot be told apart and stays in its
stage. So the fractions say where the running threads were, which is where CPU goes when the
cores are busy; ``cpu_ms_per_frame`` spreads the CPU measured per frame (from /proc) over the
stages by those fractions: an estimate, not a timer per stage.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

STAGES: tuple[str, ...] = (
    "decode",
    "features",
    "retrieval",
    "belief",
    "policy",
    "homing",
    "motion",
    "encode",
    "persist",
    "http",
)
"""Stage names in the order of a frame's path through the server."""

#: (stage, function names as py-spy prints them): the first of these met walking a stack from
#: its root names the stage; a stack inside ``Navigator.step`` that meets none is ``motion``.
MARKERS: tuple[tuple[str, frozenset[str]], ...] = (
    ("decode", frozenset({"decode_jpeg"})),
    ("features", frozenset({"extract"})),
    ("retrieval", frozenset({"TourRuntime.observe"})),
    ("belief", frozenset({"Tracker.step", "Tracker.update", "Tracker.predict"})),
    ("policy", frozenset({"decide"})),
    ("homing", frozenset({"match_views", "LazyFits.__getitem__"})),
    ("encode", frozenset({"frame_result", "NavigationService._tell", "serialize_response"})),
    ("persist", frozenset({"NavigationService._persist"})),
)
_STAGE_OF_NAME = {name: stage for stage, names in MARKERS for name in names}

WAITS: frozenset[str] = frozenset(
    {
        "Condition.wait",
        "Event.wait",
        "Semaphore.acquire",
        "BoundedSemaphore.acquire",
        "Thread.join",
        "Thread._wait_for_tstate_lock",
        "Queue.get",
        "SimpleQueue.get",
    }
)
"""Leaf functions where a thread sits waiting (for a lock, a queue, another thread)."""
_MOTION_ROOT = "Navigator.step"


def function_name(frame: str) -> str:
    """``"Navigator.step (server/navigation/navigator.py:174)"`` -> ``"Navigator.step"``."""
    return frame.split(" (", 1)[0].strip()


def stage_of(stack: Iterable[str]) -> str:
    """The stage (one of :data:`STAGES`) of a sampled stack, frames listed root first."""
    in_step = False
    for frame in stack:
        name = function_name(frame)
        stage = _STAGE_OF_NAME.get(name)
        if stage is not None:
            return stage
        in_step = in_step or name == _MOTION_ROOT
    return "motion" if in_step else "http"


def parse_raw(text: str) -> Counter[tuple[str, ...]]:
    """py-spy's raw format (one ``frame;frame;... count`` line per distinct stack) as counts
    per stack (root first). Lines that are not of that form are skipped."""
    counts: Counter[tuple[str, ...]] = Counter()
    for line in text.splitlines():
        stack, _, n = line.rstrip().rpartition(" ")
        if not stack or not n.isdigit():
            continue
        counts[tuple(stack.split(";"))] += int(n)
    return counts


@dataclass(frozen=True)
class StageProfile:
    """Samples per stage (``samples[s]`` for every ``s`` in :data:`STAGES`) and the hottest
    leaf functions (``(frame, samples)``, most first)."""

    samples: dict[str, int]
    hottest: tuple[tuple[str, int], ...]
    waiting: int = 0

    @property
    def total(self) -> int:
        return sum(self.samples.values())

    def fractions(self) -> dict[str, float]:
        """Each stage's share of all samples (0 for every stage when nothing was sampled)."""
        total = self.total
        return {s: (self.samples[s] / total if total else 0.0) for s in STAGES}

    def as_json(self, cpu_ms_per_frame: float | None) -> dict[str, Any]:
        """The profile for a benchmark's JSON; with ``cpu_ms_per_frame`` (ms of server CPU per
        answered frame) each stage's share of it too."""
        fractions = self.fractions()
        out: dict[str, Any] = {
            "samples": self.total,
            "waiting_samples": self.waiting,
            "fraction": {s: round(f, 4) for s, f in fractions.items()},
            "hottest": [{"frame": f, "samples": n} for f, n in self.hottest],
        }
        if cpu_ms_per_frame is not None:
            out["cpu_ms_per_frame"] = {
                s: round(f * cpu_ms_per_frame, 3) for s, f in fractions.items()
            }
        return out


def stage_profile(counts: Counter[tuple[str, ...]], *, hottest: int = 15) -> StageProfile:
    """Add the sampled stacks up per stage, waits (:data:`WAITS`) apart; the ``hottest`` leaf
    frames by samples (waits left out)."""
    samples = dict.fromkeys(STAGES, 0)
    leaves: Counter[str] = Counter()
    waiting = 0
    for stack, n in counts.items():
        if stack and function_name(stack[-1]) in WAITS:
            waiting += n
            continue
        samples[stage_of(stack)] += n
        leaves[stack[-1]] += n
    return StageProfile(samples, tuple(leaves.most_common(hottest)), waiting)


class Sampler:
    """py-spy recording one process for ``seconds`` into ``out`` (raw format), started with
    :meth:`start` and read with :meth:`finish`. ``available()`` says whether py-spy is there."""

    def __init__(self, pid: int, seconds: float, out: Path, *, rate_hz: int = 100) -> None:
        self.pid, self.seconds, self.out, self.rate_hz = pid, seconds, out, rate_hz
        self.proc: subprocess.Popen[bytes] | None = None

    @staticmethod
    def executable() -> str | None:
        """py-spy of this Python environment (beside the interpreter), else the one on PATH."""
        beside = Path(sys.executable).parent / "py-spy"
        return str(beside) if beside.is_file() else shutil.which("py-spy")

    def start(self) -> None:
        exe = self.executable()
        if exe is None:
            raise FileNotFoundError(
                "py-spy not found beside this Python or on PATH: it comes with the project's "
                "Python packages (pip install -e .); run the benchmark from that environment"
            )
        self.proc = subprocess.Popen(
            [
                exe,
                "record",
                "--pid",
                str(self.pid),
                "--duration",
                str(max(1, round(self.seconds))),
                "--rate",
                str(self.rate_hz),
                "--format",
                "raw",
                "--nonblocking",
                "--output",
                str(self.out),
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
        )

    def finish(self, timeout_s: float = 30.0) -> StageProfile:
        """Wait for py-spy and read its samples; a clear error if it failed (e.g. no ptrace
        permission: run as a user allowed to trace the server, or see ptrace_scope)."""
        if self.proc is None:
            raise RuntimeError("Sampler.finish() before start()")
        try:
            _, err = self.proc.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            _, err = self.proc.communicate()
        if not self.out.exists():
            message = err.decode(errors="replace").strip().splitlines()
            raise RuntimeError(f"py-spy wrote no profile: {message[-1] if message else '?'}")
        return stage_profile(parse_raw(self.out.read_text()))
