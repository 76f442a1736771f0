"""The dashboard's Timeline: open a recording (or the selected robot's current task) and scrub
it frame by frame, or play it.

At the chosen frame it shows the camera beside the taught image that matched it best, the
command with its behaviour and reason, the vote mass of every action, the belief as bars and
over time (up to the frame), and the robot's path on the top-down map of the taught paths (its
most likely position, frame after frame). A recording's frames are read with
:mod:`server.recording.reader`; the current task's history is described with the recorder's
own functions (:func:`server.recording.messages.navigation_frame`), so both show the same.

The Timeline's handles are shared by every browser, like the rest of the dashboard. Only the
household's own recordings are listed, and a taught image is shown only when it is the
household's.
"""

from __future__ import annotations

import contextlib
import json
import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt
import viser
import viser.uplot

from server import schemas
from server.domain import Edge, Location, TourGraph
from server.layout import GraphLayout, fine_position, graph_layout
from server.recording import topics
from server.recording.mcapfile import encode
from server.recording.messages import navigation_frame, tour_fingerprint
from server.recording.reader import RecordedFrame, Recording, RecordingError, read_recording
from server.services.navigation import frame_result
from web.imagery import MAP_SIZE, decode_rgb, placeholder, side_by_side, top_down
from web.panels import belief_bars, belief_over_time_plot, inert, over_time_data, votes_text

if TYPE_CHECKING:
    from server.recording.store import RecordingFile
    from server.services.container import Services

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]

CURRENT = "the selected robot's current task"
"""The source option that opens the live history of the robot picked on the left."""
SPEEDS = {"1x": 1.0, "2x": 2.0, "5x": 5.0}


@dataclass(frozen=True)
class Source:
    """What the Timeline shows: frames, the tour they were recorded on, the task's goal."""

    title: str
    frames: tuple[RecordedFrame, ...]
    graph: TourGraph
    goal: str | None
    fps: float  # frames per second of robot time when recorded

    @property
    def duration(self) -> float:
        if len(self.frames) < 2:
            return 0.0
        return self.frames[-1].timestamp - self.frames[0].timestamp


def graph_of_message(tour: dict[str, Any] | None) -> TourGraph:
    """The tour a ``/tour`` message describes, without the taught motion (drawn with the
    fallback layout), for a recording whose tour is not in this database."""
    if not tour:
        return TourGraph(())
    locations = tuple(
        Location(str(loc["name"]), tuple(int(i) for i in loc["image_ids"]), int(loc["id"]))
        for loc in tour.get("locations", [])
    )
    index = {loc.id: k for k, loc in enumerate(locations)}
    edges = []
    for e in tour.get("edges", []):
        n = len(e["image_ids"])
        edges.append(
            Edge(
                index[int(e["source"])],
                index[int(e["target"])],
                tuple(int(i) for i in e["image_ids"]),
                np.zeros(n),
                np.zeros(n),
                np.zeros(n),
                int(e["id"]),
            )
        )
    return TourGraph(locations, tuple(edges))


def history_source(services: Services, robot: str) -> Source | None:
    """The robot's current task as the session keeps it (its last steps, at most
    ``NavigationParams.history``), described as a recording would describe it."""
    session = services.navigation.sessions().get(robot)
    if session is None:
        return None
    graph = session.runtime.graph
    ttl = services.navigation.params.motion.ttl_s
    fov = services.navigation.params.motion.depth_fov_deg
    frames: list[RecordedFrame] = []
    for record in list(session.history):
        if len(record.summary.state) != graph.n_states:
            continue
        meta = schemas.FrameMeta(timestamp=record.timestamp)
        result = frame_result(record, graph, None, ttl_s=ttl)
        described = navigation_frame(
            record, result, graph, meta, index=len(frames), wall=0.0, depth_fov_deg=fov
        )
        messages = {
            topic: json.loads(encode(payload))
            for topic, payload in described.messages
            if topic != topics.CAMERA
        }
        frames.append(
            RecordedFrame(
                index=len(frames),
                timestamp=record.timestamp,
                wall=0.0,
                kind="navigate",
                jpeg=record.jpeg,
                v=0.0,
                w=0.0,
                depth=None,
                messages=messages,
            )
        )
    if not frames:
        return None
    task = session.task
    span = frames[-1].timestamp - frames[0].timestamp
    return Source(
        title=f"{robot}'s current task: the last {len(frames)} frames",
        frames=tuple(frames),
        graph=graph,
        goal=None if task is None else task.goal_name,
        fps=(len(frames) - 1) / span if span > 0 else 10.0,
    )


@dataclass
class TimelineControls:
    source: viser.GuiDropdownHandle[str]
    open: viser.GuiButtonHandle
    note: viser.GuiMarkdownHandle
    frame: viser.GuiSliderHandle[int]
    play: viser.GuiButtonHandle
    pause: viser.GuiButtonHandle
    speed: viser.GuiDropdownHandle[str]
    images: viser.GuiImageHandle
    text: viser.GuiMarkdownHandle
    belief: viser.GuiMarkdownHandle
    over_time: viser.GuiUplotHandle
    map: viser.GuiImageHandle


class Timeline:
    """The Timeline tab of one dashboard (see the module docstring).

    ``household``: list that household's recordings only (``None``: every household's);
    ``selected``: the robot picked on the left (for the current task's history)."""

    def __init__(
        self,
        services: Services,
        *,
        household: int | None,
        selected: Callable[[], str | None],
        image: Callable[[int], bytes | None],
    ) -> None:
        self.services = services
        self.household = household
        self.selected = selected
        self.image = image
        self.controls: TimelineControls | None = None
        self.source: Source | None = None
        self.layout: GraphLayout | None = None
        self._positions: list[FloatArray | None] = []
        self._files: dict[str, RecordingFile] = {}
        self._lock = threading.Lock()  # one frame drawn at a time
        self._playing = threading.Event()
        self._stop = threading.Event()
        self._player: threading.Thread | None = None

    # --- layout ---------------------------------------------------------------------------

    def build(self, server: viser.ViserServer, panel: viser.PanelHandle) -> TimelineControls:
        gui = server.gui
        with panel.add_tab("Timeline"):
            source = gui.add_dropdown(
                "Recording", (CURRENT,), hint="A recorded task or tour, newest first"
            )
            open_button = gui.add_button("Open", hint="Read it and show its first frame")
            note = gui.add_markdown(
                "Open a recording (or the current task) to go through it frame by frame."
            )
            frame = gui.add_slider("Frame", 0, 1, 1, 0, disabled=True)
            with gui.add_folder("Play", expand_by_default=True):
                play = gui.add_button("Play", color="blue", disabled=True)
                pause = gui.add_button("Pause", disabled=True)
                speed = gui.add_dropdown("Speed", tuple(SPEEDS), initial_value="1x")
            images = gui.add_image(
                side_by_side(None, None, ("camera", "matched taught image")),
                label=None,
                format="jpeg",
            )
            text = gui.add_markdown("")
            belief = gui.add_markdown("")
            over_time = belief_over_time_plot(gui, "belief over time, up to this frame")
            the_map = gui.add_image(
                placeholder("path on the taught map", width=MAP_SIZE[0], height=MAP_SIZE[1]),
                label=None,
                format="png",
            )
        c = self.controls = TimelineControls(
            source,
            open_button,
            note,
            frame,
            play,
            pause,
            speed,
            images,
            text,
            belief,
            over_time,
            the_map,
        )
        open_button.on_click(self._on_open)
        frame.on_update(lambda _: self.show(int(frame.value)))
        play.on_click(lambda _: self.play())
        pause.on_click(lambda _: self.pause())
        return c

    def _on_open(self, _: viser.GuiEvent[viser.GuiButtonHandle]) -> None:
        self.open_selected()

    def refresh_sources(self) -> None:
        """List the household's recordings in the dropdown (newest first)."""
        c = self.controls
        if c is None:
            return
        files = self.services.recordings.store.files(self.household)
        self._files = {_label(f): f for f in files}
        options = (CURRENT, *self._files)
        if tuple(c.source.options) != options:
            c.source.options = options

    def close(self) -> None:
        self._stop.set()
        self._playing.clear()
        if self._player is not None:
            self._player.join(timeout=5)

    # --- opening ----------------------------------------------------------------------------

    def open_selected(self) -> str:
        """Open what the dropdown names; the message shown (also returned)."""
        c = self.controls
        if c is None:
            return ""
        self.pause()
        choice = c.source.value
        try:
            if choice == CURRENT:
                robot = self.selected()
                source = None if robot is None else history_source(self.services, robot)
                if source is None:
                    raise RecordingError(
                        "the selected robot has no navigation frames yet: send it somewhere "
                        "(Go), or open a recording"
                    )
            else:
                found = self._files.get(choice)
                if found is None:
                    raise RecordingError(f"no recording {choice!r} here any more")
                source = self.recording_source(read_recording(found.path))
        except RecordingError as exc:
            c.note.content = "**Error:** " + inert(str(exc))
            return str(exc)
        self.open(source)
        return c.note.content

    def recording_source(self, rec: Recording) -> Source:
        """A recording with the tour it was made on: this database's when its fingerprint
        matches (and it is the household's), else the one the file describes."""
        meta = rec.meta
        tour_message = rec.tour or {}
        graph = None
        with contextlib.suppress(Exception):  # no such tour here, another household's...
            tour_id = int(meta.get("tour", "0"))
            self.services.repo.tour(tour_id, self.household)
            stored = self.services.repo.graph(tour_id)
            if rec.kind == "teach" or tour_fingerprint(stored) == meta.get("fingerprint"):
                graph = stored
        if graph is None:
            graph = graph_of_message(tour_message)
        what = f"task to {meta.get('goal')}" if rec.kind == "navigate" else "teaching tour"
        cut = "" if rec.complete else " (cut short: up to its last whole frame)"
        return Source(
            title=f"{meta.get('robot', '?')}'s {what}, {rec.path.name}{cut}",
            frames=rec.frames,
            graph=graph,
            goal=meta.get("goal"),
            fps=rec.realtime_fps() or 10.0,
        )

    def open(self, source: Source) -> None:
        """Show ``source`` from its first frame."""
        c = self.controls
        assert c is not None
        self.source = source
        graph = source.graph
        self.layout = graph_layout(graph) if graph.n_locations else None
        self._positions = [self._position(f) for f in source.frames]
        n = len(source.frames)
        c.note.content = inert(
            f"**{source.title}**: {n} frames over {source.duration:.1f} s of robot time."
        )
        c.frame.max = max(1, n - 1)
        c.frame.disabled = n < 2
        c.play.disabled = c.pause.disabled = n < 2
        c.over_time.visible = any(f.belief is not None for f in source.frames)
        if int(c.frame.value) != 0:
            _set(c.frame, 0)  # shows it (the slider's callback)
        else:
            self.show(0)

    def _position(self, frame: RecordedFrame) -> FloatArray | None:
        belief, layout, source = frame.belief, self.layout, self.source
        if belief is None or layout is None or source is None:
            return None
        fine = int(belief.get("position", {}).get("fine", -1))
        if not 0 <= fine < source.graph.n_fine:
            return None
        return fine_position(layout, source.graph, fine)

    # --- one frame --------------------------------------------------------------------------

    def show(self, k: int) -> None:
        """Draw frame ``k`` of the open source."""
        c, source = self.controls, self.source
        if c is None or source is None or not source.frames:
            return
        with self._lock:
            k = int(np.clip(k, 0, len(source.frames) - 1))
            frame = source.frames[k]
            images = self._images(frame, k, len(source.frames))
            text, bars = self._texts(frame, source.graph)
            over = self._over_time(source, k)
            the_map = self._map(source, k)
            c.images.image = images  # the assignments are cheap: everything is prepared
            c.text.content = text
            c.belief.content = bars
            if over is not None:
                c.over_time.data = over
            if the_map is not None:
                c.map.image = the_map

    def _images(self, frame: RecordedFrame, k: int, n: int) -> npt.NDArray[np.uint8]:
        camera = decode_rgb(frame.jpeg)
        belief = frame.belief
        matched, caption = None, "no belief (teaching)" if belief is None else "matched: -"
        best = None if belief is None else belief.get("best") or {}
        if best and best.get("image_id") is not None:
            matched = decode_rgb(self.image(int(best["image_id"])))
            state = int(best.get("state", 0))
            name = self.source.graph.state_name(state) if self.source else "?"
            sim = best.get("similarity")
            caption = f"matched: {name}" + ("" if sim is None else f" ({sim:.2f})")
        left = f"frame {k + 1}/{n}  t={frame.timestamp:.1f} s"
        return side_by_side(camera, matched, (left, caption))

    def _texts(self, frame: RecordedFrame, graph: TourGraph) -> tuple[str, str]:
        command, votes, belief = frame.command, frame.votes, frame.belief
        state = frame.messages.get(topics.FRAME, {}).get("task_state")
        if command is None:
            kind = "spin image" if frame.kind == "spin" else "frame of the open path"
            return inert(f"Teaching: {kind}, v {frame.v:.2f} m/s, w {frame.w:.2f} rad/s"), ""
        why = f"\n\nWhy: {command['reason']}" if command.get("reason") else ""
        task = f"\n\nTask: **{state}**" if state else ""
        loc = "" if belief is None else f" - entropy {belief['entropy']:.2f} nats"
        text = (
            f"**{command['action']}** ({command['behaviour']}) - v {command['v']:.2f} m/s, "
            f"w {command['w']:.2f} rad/s{loc}{why}{task}\n\n"
            + votes_text({} if votes is None else dict(votes["votes"]))
        )
        bars = "" if belief is None else belief_bars(belief["states"], graph)
        return inert(text), inert(bars)

    def _over_time(self, source: Source, k: int) -> tuple[FloatArray, ...] | None:
        beliefs = [f.belief for f in source.frames[: k + 1]]
        if not beliefs or beliefs[0] is None:
            return None
        t = np.array([f.timestamp for f in source.frames[: k + 1]])
        top = np.array([max(b["states"]) if b else 0.0 for b in beliefs])
        entropy = np.array([b["entropy"] if b else 0.0 for b in beliefs])
        return over_time_data(t, top, entropy, source.graph.n_states)

    def _map(self, source: Source, k: int) -> npt.NDArray[np.uint8] | None:
        if self.layout is None:
            return None
        frame = source.frames[k]
        trail = [p for p in self._positions[: k + 1] if p is not None]
        belief = frame.belief
        return top_down(
            source.graph,
            self.layout,
            states=None if belief is None else belief["states"],
            position=self._positions[k],
            trail=np.asarray(trail) if len(trail) > 1 else None,
            goal=source.goal,
        )

    # --- playing ----------------------------------------------------------------------------

    def play(self) -> None:
        """Step through the frames at the recorded rate times the speed, from the current."""
        self._playing.set()
        if self._player is None or not self._player.is_alive():
            self._player = threading.Thread(target=self._run, name="timeline", daemon=True)
            self._player.start()

    def pause(self) -> None:
        self._playing.clear()

    def _run(self) -> None:
        while not self._stop.is_set() and self._playing.is_set():
            c, source = self.controls, self.source
            if c is None or source is None:
                return
            k = int(c.frame.value)
            if k >= len(source.frames) - 1:
                self._playing.clear()
                return
            speed = SPEEDS.get(c.speed.value, 1.0)
            self._stop.wait(1.0 / max(source.fps * speed, 0.1))
            _set(c.frame, k + 1)  # draws the frame (the slider's callback)


def _set(handle: Any, value: object) -> None:
    """``handle.value = value`` (viser's setter, which also runs the handle's callbacks)."""
    handle.value = value


def _label(found: RecordingFile) -> str:
    """A recording's entry in the dropdown: its file name."""
    return found.name


__all__ = ["CURRENT", "Source", "Timeline", "graph_of_message", "history_source"]
