"""The dashboard's panels: the controls on the left, the camera and belief on the right, and
the texts and plot data they show.

:func:`build_panels` lays the GUI out and returns its handles (:class:`Controls`); the
functions below turn a snapshot into what those handles show. Every text a user or a robot
could have chosen goes through :func:`inert` before it reaches viser's markdown.
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt
import viser
import viser.uplot
from pydantic import ValidationError

from server.errors import DomainError
from web.drive import DIRECTIONS, keyboard_bridge
from web.imagery import MAP_SIZE, behaviour_strip, captioned, placeholder, side_by_side

if TYPE_CHECKING:
    from server.domain import TourGraph
    from server.schemas import LearnedChange, QuestionPublic, RobotControlPublic
    from web.publisher import Snapshot, StepView

FloatArray = npt.NDArray[np.float64]

NONE = "—"
"""Placeholder option of a dropdown with nothing to choose."""
ACTIONS = ("navigate", "rotate_and_find_edge", "explore", "do_nothing")
LEFT_WIDTH = 360
RIGHT_WIDTH = 480
"""Widths (px) of the docked panels; the 3D view gets what is left between them."""


@dataclass
class Controls:
    """The GUI handles; assigning ``.value = True`` to a button clicks it (as tests do)."""

    message: viser.GuiMarkdownHandle
    robot: viser.GuiDropdownHandle[str]
    status: viser.GuiMarkdownHandle
    tour: viser.GuiDropdownHandle[str]
    goal: viser.GuiDropdownHandle[str]
    record: viser.GuiCheckboxHandle
    go: viser.GuiButtonHandle
    stop: viser.GuiButtonHandle
    teaching: viser.GuiMarkdownHandle
    teach_tour: viser.GuiTextHandle
    teach_start: viser.GuiButtonHandle
    place_name: viser.GuiTextHandle
    mark: viser.GuiButtonHandle
    finish: viser.GuiButtonHandle
    abort: viser.GuiButtonHandle
    drive_note: viser.GuiMarkdownHandle
    speed: viser.GuiSliderHandle[float]
    turn: viser.GuiSliderHandle[float]
    arrows: dict[str, viser.GuiButtonHandle]  # Direction.name -> its button
    map: viser.GuiImageHandle
    learned: viser.GuiMarkdownHandle
    question: viser.GuiMarkdownHandle
    yes: viser.GuiButtonHandle
    no: viser.GuiButtonHandle
    images: viser.GuiImageHandle
    action: viser.GuiMarkdownHandle
    strip: viser.GuiImageHandle
    target: viser.GuiImageHandle
    votes: viser.GuiMarkdownHandle
    plots_note: viser.GuiMarkdownHandle
    along_label: viser.GuiMarkdownHandle
    along_edge: viser.GuiUplotHandle
    over_time: viser.GuiUplotHandle
    panel: viser.PanelHandle  # the right panel: the timeline adds its tab to it

    @property
    def teach_inputs(self) -> tuple[viser.GuiTextHandle | viser.GuiButtonHandle, ...]:
        """What is shown only while the robot is teaching."""
        return (self.place_name, self.mark, self.finish, self.abort)

    @property
    def teach_starters(self) -> tuple[viser.GuiTextHandle | viser.GuiButtonHandle, ...]:
        """What is shown only while the robot is not teaching."""
        return (self.teach_tour, self.teach_start)

    @property
    def drive_inputs(self) -> tuple[viser.GuiSliderHandle[float] | viser.GuiButtonHandle, ...]:
        """What is shown only while the robot can be driven by hand (connected, and not
        navigating)."""
        return (self.speed, self.turn, *self.arrows.values())

    @property
    def plots(self) -> tuple[viser.GuiMarkdownHandle | viser.GuiUplotHandle, ...]:
        """What is shown only once the robot has navigation frames."""
        return (self.along_label, self.along_edge, self.over_time)


def build_panels(
    server: viser.ViserServer,
    *,
    household_line: str | None,
    max_v: float = 0.3,
    max_w: float = 1.0,
) -> Controls:
    """Lay out the dashboard's GUI: theme, grid, the left panel (robot, driving, goal,
    teaching, map) and the right one (camera and belief); ``household_line``: a markdown line
    on top; ``max_v`` (m/s) and ``max_w`` (rad/s): the server's speed limit for driving by
    hand (the sliders' ends)."""
    gui = server.gui
    gui.configure_theme(
        control_width="large",
        show_share_button=False,
        show_logo=False,
        brand_color=(37, 99, 235),
        titlebar_content=None,
    )
    gui.set_panel_label("teachrepeat")
    server.scene.set_up_direction("+z")
    server.scene.add_grid(
        "/grid",
        width=40.0,
        height=40.0,
        plane="xy",
        position=(0.0, 0.0, -0.02),
        cell_color=(225, 228, 235),
        section_color=(200, 205, 215),
        shadow_opacity=0.0,
    )
    main = gui.main_panel
    main.dock_left()
    main.set_width(LEFT_WIDTH)
    if household_line is not None:
        gui.add_markdown(household_line)
    message = gui.add_markdown("")
    gui.add_html(keyboard_bridge())  # the keys hold the arrows (web/drive.py)
    gui.add_markdown(
        "Places are spheres, taught paths lines; colour and size show the belief "
        "(slate 0, blue, amber, red 1). The ring is the most likely position."
    )
    with gui.add_folder("Robot"):
        robot = gui.add_dropdown("Robot", (NONE,), hint="The robot shown and controlled")
        status = gui.add_markdown("*waiting for the first snapshot...*")
    with gui.add_folder("Drive"):
        drive_note = gui.add_markdown(drive_text(None, None))
        speed = gui.add_slider(
            "Speed (m/s)",
            min=0.05,
            max=round(max_v, 2),
            step=0.05,
            initial_value=round(min(0.25, max_v), 2),
            hint="Forward and back speed while an arrow is held (the server's limit at the end)",
            visible=False,
        )
        turn = gui.add_slider(
            "Turn (rad/s)",
            min=0.1,
            max=round(max_w, 2),
            step=0.1,
            initial_value=round(min(0.6, max_w), 2),
            hint="Turn rate while an arrow is held",
            visible=False,
        )
        arrows = {
            d.name: gui.add_button(
                d.label,
                hint=f"Hold to drive ({' or '.join(key_name(k) for k in d.keys)}); release to stop",
                visible=False,
            )
            for d in DIRECTIONS
        }
    with gui.add_folder("Go to a place"):
        tour = gui.add_dropdown("Tour", (NONE,), hint="The tour whose places are listed")
        goal = gui.add_dropdown("Goal", (NONE,), hint="Where the robot should go")
        record = gui.add_checkbox(
            "Record", False, hint="Record the task to an MCAP file (Timeline tab, Foxglove)"
        )
        go = gui.add_button("Go", color="blue", hint="POST /robots/{robot}/goto")
        stop = gui.add_button(
            "Stop",
            color="red",
            hint="Stop whatever the robot does: a task, a spin, driving (POST .../halt)",
        )
    with gui.add_folder("Teach"):
        teaching = gui.add_markdown("")
        teach_tour = gui.add_text(
            "Tour to teach",
            "",
            hint="A new name creates the tour; an existing one adds to it; empty: the tour "
            "chosen above",
        )
        teach_start = gui.add_button(
            "Start teaching", color="green", hint="POST /robots/{robot}/teach/start"
        )
        place_name = gui.add_text("Name this place", "", hint="e.g. kitchen", visible=False)
        mark = gui.add_button("Mark", hint="POST /robots/{robot}/teach/locations", visible=False)
        finish = gui.add_button(
            "Finish", color="green", hint="POST .../teach/finish", visible=False
        )
        abort = gui.add_button("Abort", color="gray", hint="POST .../teach/abort", visible=False)
    with gui.add_folder("Map"):
        the_map = gui.add_image(
            placeholder("no tour yet", width=MAP_SIZE[0], height=MAP_SIZE[1]),
            label=None,
            format="png",
        )

    with gui.add_folder("Questions"):
        question = gui.add_markdown(questions_text(()))
        yes = gui.add_button(
            "Yes", color="green", hint="POST /robots/{robot}/questions/{id} yes", visible=False
        )
        no = gui.add_button(
            "No", color="red", hint="POST /robots/{robot}/questions/{id} no", visible=False
        )
    with gui.add_folder("Learned", expand_by_default=False):
        learned = gui.add_markdown(learned_text(()))

    panel = gui.add_panel()
    with panel.add_tab("Camera and belief"):
        images = gui.add_image(
            side_by_side(None, None, ("camera", "best match")), label=None, format="jpeg"
        )
        action = gui.add_markdown("")
        strip = gui.add_image(behaviour_strip(()), label=None, format="png")
        target = gui.add_image(
            captioned(None, "target image", height=120), label=None, format="jpeg"
        )
        votes = gui.add_markdown("")
        plots_note = gui.add_markdown("")
        along_label = gui.add_markdown("", visible=False)
        along_edge = gui.add_uplot(
            data=(np.zeros(1), np.zeros(1), np.zeros(1)),
            series=(
                viser.uplot.Series(label="image"),
                viser.uplot.Series(label="b(i|e)", stroke="#dc2626", width=2),
                viser.uplot.Series(label="similarity", stroke="#2563eb", width=1.5),
            ),
            title="belief along the active path (by image)",
            scales={"x": viser.uplot.Scale(time=False, auto=True)},
            legend=viser.uplot.Legend(show=True),
            aspect=2.0,
            visible=False,
        )
        over_time = belief_over_time_plot(gui, "top belief over time")
    panel.dock_right()
    panel.set_width(RIGHT_WIDTH)
    return Controls(
        message=message,
        robot=robot,
        status=status,
        tour=tour,
        goal=goal,
        record=record,
        go=go,
        stop=stop,
        teaching=teaching,
        teach_tour=teach_tour,
        teach_start=teach_start,
        place_name=place_name,
        mark=mark,
        finish=finish,
        abort=abort,
        drive_note=drive_note,
        speed=speed,
        turn=turn,
        arrows=arrows,
        map=the_map,
        learned=learned,
        question=question,
        yes=yes,
        no=no,
        images=images,
        action=action,
        strip=strip,
        target=target,
        votes=votes,
        plots_note=plots_note,
        along_label=along_label,
        along_edge=along_edge,
        over_time=over_time,
        panel=panel,
    )


def questions_text(questions: Sequence[QuestionPublic], now: float | None = None) -> str:
    """The selected robot's open questions (docs/learning.md): the oldest, which the Yes and
    No buttons answer, then how many more wait (markdown; the dashboard puts it through
    :func:`inert`)."""
    if not questions:
        return "*No question from the robot.*"
    first = questions[0]
    left = "" if now is None else f" (answer within {max(0.0, first.expires_at - now):.0f} s)"
    lines = [f"**{first.text}**{left}"]  # made inert where it is shown
    if first.kind == "same_place":
        lines.append("Yes joins the path taught to that place; no keeps them apart.")
    else:
        lines.append("Yes adds the way found as a path of the map; no discards it.")
    if len(questions) > 1:
        lines.append(f"{len(questions) - 1} more waiting.")
    return "\n\n".join(lines)


def learned_text(changes: Sequence[LearnedChange]) -> str:
    """The selected tour's learned changes (docs/learning.md), newest first: what, when, from
    which question; undo one with DELETE /tours/{tour}/learned/{id}."""
    if not changes:
        return "*The tour has learned nothing from answered questions.*"
    lines = [
        f"- **#{c.id} {c.kind}** {time.strftime('%Y-%m-%d %H:%M', time.gmtime(c.created_at))}"
        f": {inert(c.summary)} (from {inert(c.source)})"
        for c in sorted(changes, key=lambda c: -c.id)
    ]
    return "\n".join([*lines, "", "Undo one: `DELETE /tours/{tour}/learned/{id}`."])


def belief_over_time_plot(gui: viser.GuiApi, title: str) -> viser.GuiUplotHandle:
    """A plot (hidden until there is data) of the top belief and the entropy over its
    maximum against robot seconds (:func:`over_time_data`)."""
    return gui.add_uplot(
        data=(np.zeros(1), np.zeros(1), np.zeros(1)),
        series=(
            viser.uplot.Series(label="t (s)"),
            viser.uplot.Series(label="top b(s)", stroke="#dc2626", width=2),
            viser.uplot.Series(label="entropy / max", stroke="#6b7280", width=1.5),
        ),
        title=title,
        scales={
            "x": viser.uplot.Scale(time=False, auto=True),
            "y": viser.uplot.Scale(auto=False, range=(0.0, 1.0)),
        },
        legend=viser.uplot.Legend(show=True),
        aspect=2.0,
        visible=False,
    )


# --- texts -----------------------------------------------------------------------------------


def status_text(snap: Snapshot) -> str:
    """What the selected robot is doing, which tour is shown, and what the others do."""
    if snap.robot is None:
        return "No robot registered yet: `POST /robots` (admin token) registers one."
    lines = [f"**{snap.robot}** is **{snap.mode}**"]
    if snap.tour_name is not None:
        if snap.bound:
            lines[0] += f" - tour *{snap.tour_name}*"
        else:
            lines[0] += f"; showing tour *{snap.tour_name}*"
    task = snap.task
    if task is not None:
        text = f"Task {task.id} to **{task.goal}**: **{task.state}** after {task.steps} steps"
        if task.reason:
            text += f" ({task.reason})"
        lines.append(text)
    elif snap.mode == "idle":
        lines.append("No task. Pick a goal and press **Go**.")
    step = snap.step
    if step is not None:
        lines.append(f"Last frame t = {step.timestamp:.1f} s, step {step.step_ms:.0f} ms")
    others = [f"**{robot}** is {doing}" for robot, doing in snap.activity if robot != snap.robot]
    if others:
        lines.append("Also: " + "; ".join(others) + " (pick it above to watch).")
    return "\n\n".join(lines)


def teaching_text(snap: Snapshot) -> str:
    t = snap.teaching
    if t is None:
        return (
            "Not teaching. Name a tour (or choose one above) and press **Start teaching**; "
            "then drive the robot and name each place where it stands."
        )
    at = f"at **{t.current_location}**" if t.current_location else "no place named yet"
    lines = [
        f"Teaching *{t.tour_name}*: {at}; **{t.open_path_images}** images on the open path; "
        f"{t.locations} places and {t.edges} paths so far."
    ]
    spin = None if snap.control is None else snap.control.spin
    if spin is not None and spin.state == "spinning":
        lines.append(
            f"Turning at **{spin.place}** to photograph it: {spin.turned_deg:.0f} of 360 "
            f"degrees, {spin.images} images."
        )
    elif spin is not None:
        how = {"done": "spun", "timeout": "spin timed out", "stopped": "spin stopped"}
        lines.append(f"{how.get(spin.state, spin.state)} at {spin.place}: {spin.images} images.")
    if t.current_location is None:
        lines.append("Name the place where the robot stands to begin.")
    elif t.open_path_images:
        lines.append("Name the place where the robot stands now, or drive on.")
    return "\n\n".join(lines)


def key_name(code: str) -> str:
    """A key as people name it: ``ArrowUp`` -> ``↑``, ``KeyW`` -> ``W``."""
    arrows = {"ArrowUp": "↑", "ArrowDown": "↓", "ArrowLeft": "←", "ArrowRight": "→"}
    return arrows.get(code, code.removeprefix("Key"))


def drive_text(control: RobotControlPublic | None, mode: str | None) -> str:
    """How to drive the selected robot, or why it cannot be driven now."""
    if control is None or not control.connected:
        return (
            "*The robot sends no frames:* start its agent (`teachrepeat robot run`) to drive "
            "it from here."
        )
    if mode == "navigating":
        return "Navigating: press **Stop** to drive it by hand."
    spin = control.spin
    if spin is not None and spin.state == "spinning":
        return f"Turning at **{spin.place}** to photograph it; the arrows wait."
    keys = "arrow keys or W A S D"
    line = f"Hold an arrow (or the {keys}) to drive; release to stop."
    t = control.teleop
    if t is not None:
        line += f" Driving: v {t.v:.2f} m/s, w {t.w:.2f} rad/s."
    return line


def live_text(snap: Snapshot) -> str:
    """What the robot was told with its latest frame (outside navigation)."""
    live = snap.live
    if live is None:
        return "*no frames from the robot yet*"
    c = live.command
    why = f"\n\nWhy: {c.reason}" if c.reason else ""
    return (
        f"**Command: {c.behaviour}** - v {c.v:.2f} m/s, w {c.w:.2f} rad/s "
        f"(for {c.ttl_s:.2f} s){why}"
    )


def action_text(step: StepView, graph: TourGraph) -> str:
    where = ""
    if step.action_edge is not None and 0 <= step.action_edge < graph.n_edges:
        where = f" on {graph.state_name(graph.n_locations + step.action_edge)}"
    top = ", ".join(f"{graph.state_name(s)} {p:.2f}" for s, p in step.top_states[:3])
    loc = "yes" if step.localised else "no"
    why = f"Why: {step.reason}\n\n" if step.reason else ""
    return (
        f"**Action: {step.action}**{where} ({step.behaviour}) - v {step.v:.2f} m/s, "
        f"w {step.w:.2f} rad/s\n\n{why}"
        f"Top states: {top}\n\n"
        f"Entropy **{step.entropy:.2f}** nats - localised: {loc}\n\n"
        f"{appearance_text(step)}"
    )


APPEARANCE_MODELS = ("as taught", "changed light")
"""Names of the engine's appearance models, in TourIndex.model_weights() order."""


def appearance_text(step: StepView) -> str:
    """Which appearance model the belief trusts, and each model's signature block weights."""
    blocks = ("hist", "thumb", "desc_mean", "desc_var", "patch")
    parts = []
    for k, p in enumerate(step.appearance):
        name = APPEARANCE_MODELS[k] if k < len(APPEARANCE_MODELS) else f"model {k}"
        w = step.model_weights[k] if k < len(step.model_weights) else ()
        shown = " ".join(f"{b} {x:.2f}" for b, x in zip(blocks, w, strict=False) if x >= 0.005)
        parts.append(f"{name} **{p:.2f}**" + (f" ({shown})" if shown else ""))
    change = (
        f"; light changed **{step.light_change:.2f}** (0: the tour's own light)"
        if len(step.appearance) > 1
        else ""
    )
    return "Appearance: " + "; ".join(parts) + change


def votes_text(votes: dict[str, float]) -> str:
    """The vote mass of every action as text bars."""
    if not votes:
        return "*no votes: no task underway*"
    rows = [f"{a:<22}{bar(votes.get(a, 0.0))} {votes.get(a, 0.0):.2f}" for a in ACTIONS]
    return "Vote mass\n```\n" + "\n".join(rows) + "\n```"


def belief_bars(states: npt.ArrayLike, graph: TourGraph, *, top: int = 6) -> str:
    """The ``top`` most likely places and paths of ``states`` (``(n_states,)`` b(s)) as bars,
    one line each: bar, probability, name (names outside code: :func:`inert` applies)."""
    b = np.asarray(states, dtype=np.float64)
    if len(b) != graph.n_states:
        return "*no belief*"
    order = np.argsort(-b, kind="stable")[:top]
    rows = [f"`{bar(float(b[s]))}` {float(b[s]):.2f} {graph.state_name(int(s))}" for s in order]
    return "**Belief**  \n" + "  \n".join(rows)


def along_edge_data(step: StepView, graph: TourGraph) -> tuple[str, tuple[FloatArray, ...]] | None:
    n_loc = graph.n_locations
    edge = step.active_edge
    if edge is None and graph.n_edges:
        edge = int(np.argmax(step.state_belief[n_loc:]))
    if edge is None or not 0 <= edge < len(step.along_edge) or graph.edges[edge].n_images == 0:
        return None
    b = step.along_edge[edge]
    x = np.arange(len(b), dtype=np.float64)
    # canonical order: every place's spin images, then every edge's images in edge order
    first = graph.n_images - int(graph.edge_offsets[-1]) + int(graph.edge_offsets[edge])
    sims = step.image_similarity[first : first + len(b)]
    if len(sims) != len(b):
        sims = np.zeros(len(b))
    return graph.state_name(n_loc + edge), (x, b, sims)


def over_time_data(
    t: FloatArray, top: FloatArray, entropy: FloatArray, n_states: int
) -> tuple[FloatArray, ...]:
    """The top belief and the entropy (over its maximum) against robot seconds from the first
    frame."""
    if len(t) == 0:
        return (np.zeros(1), np.zeros(1), np.zeros(1))
    h_max = math.log(max(2, n_states))
    return (t - t[0], top, entropy / h_max)


def error_text(exc: Exception) -> str:
    """What to tell the user about a refused action."""
    if isinstance(exc, DomainError):
        return exc.message
    if isinstance(exc, ValidationError):
        parts = []
        for err in exc.errors():
            where = ".".join(str(p) for p in err.get("loc", ())) or "input"
            parts.append(f"{where}: {err.get('msg', 'invalid')}")
        return "invalid input - " + "; ".join(parts)
    return f"unexpected error: {exc}"


_NOT_MARKUP = str.maketrans({"&": "&amp;", "<": "&lt;", ">": "&gt;", "[": "\\[", "]": "\\]"})


def inert(markdown: str) -> str:
    """``markdown`` with no raw HTML and no links: ``&``, ``<`` and ``>`` as character
    references, brackets escaped. viser renders the HTML inside markdown unsanitised, and the
    texts shown carry names anyone with a token chose (tours, places, reasons quoting them):
    a tour named ``<style>...`` must not restyle or overlay the dashboard. Bold and italics
    stay; the texts put through here hold no HTML, link or bracket of their own."""
    return markdown.translate(_NOT_MARKUP)


def bar(p: float, width: int = 16) -> str:
    filled = round(max(0.0, min(1.0, p)) * width)
    return "█" * filled + "·" * (width - filled)


def tour_label(tour_id: int, name: str) -> str:
    return f"{name} (#{tour_id})"


def tour_id_of(label: str) -> int | None:
    found = re.search(r"\(#(\d+)\)$", label)
    return int(found.group(1)) if found else None
