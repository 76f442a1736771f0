"""The live dashboard: a viser app on its own port, fed by the :class:`~web.publisher.Publisher`.

What it shows, for the robot picked in the selector and the tour it uses: the tour graph in 3D
(:mod:`web.scene`: places as named spheres, taught paths as lines, laid out from the recorded
odometry when the tour has it), the belief per place and path as colour and size and along
each path as coloured points, a top-down map of the taught paths with the robot's most likely
position, the camera frame beside the best-matching stored image, the action with its
target image and the vote mass of every action, the belief entropy, plots of the belief along
the active path and of the top belief over time (shown once there are frames), the navigation
task, what the other robots are doing, and the teaching progress. The Timeline tab
(:mod:`web.timeline`) opens a recording, or the current task's history, and scrubs it.

The dashboard is split by what it draws: :mod:`web.panels` lays the GUI out and writes its
texts, :mod:`web.scene` the 3D graph, :mod:`web.imagery` the images (camera tiles, behaviour
strip, map), :mod:`web.timeline` the Timeline; this module wires them to the snapshots and the
controls to the services.

Controls (robot selector; the Drive arrows and keys, :mod:`web.drive`; goal, Record, Go,
Stop; a tour to teach and Start teaching; while teaching: place name, Mark, Finish, Abort)
call the same service layer as the REST routes, so the same checks apply; a refused action
shows its message. Every action is written to the audit log (actor ``household:NAME``, or
``dashboard`` for the all-households view); driving by hand is audited when a drive starts,
not at every repeat of a held arrow. While the robot is not navigating, the camera shows its
latest frame and the command it was given (teleop, spin, stand).

One dashboard shows one household (``household=id``: its robots, tours and recordings only,
and every action first checks that the robot is that household's, so a forged GUI message
cannot drive another household's robot) or, with ``household=None``, every household: the
loopback default. Off loopback, :mod:`web.gate` serves each logged-in household its own
dashboard.

Design (STYLE principle 9): the dashboard holds viser handles, not state. Its selection lives
in the selector handles; everything drawn comes from the latest snapshot. The GUI and scene are
*shared* (``server.gui`` / ``server.scene``): every browser sees the same robot, and the cost of
a refresh does not grow with the number of browsers. All live updates happen in the publisher
thread (button callbacks only call services and write the message line; the Timeline draws in
its own callbacks); arrays and images are prepared before ``server.atomic()`` so nothing blocks
inside it, and no lock is held while talking to viser.
"""

from __future__ import annotations

import logging
import threading
import time
import warnings
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Literal

import viser
from pydantic import ValidationError

from server import schemas
from server.errors import Conflict, DomainError, NotFound
from server.layout import GraphLayout, fine_position, graph_layout, tracked_position
from server.services.questions import change_public
from web.ambiguity import distinctiveness_text, step_lines
from web.drive import DRIVE_HZ, HOLD_TTL_S, drive_command
from web.imagery import (
    MAP_SIZE,
    Tracked,
    behaviour_strip,
    captioned,
    decode_rgb,
    placeholder,
    side_by_side,
    top_down,
)
from web.panels import (
    NONE,
    Controls,
    action_text,
    along_edge_data,
    build_panels,
    drive_text,
    error_text,
    inert,
    learned_text,
    live_text,
    over_time_data,
    questions_text,
    status_text,
    teaching_text,
    tour_id_of,
    tour_label,
    votes_text,
)
from web.publisher import Publisher, Snapshot
from web.scene import GraphScene
from web.timeline import Timeline

if TYPE_CHECKING:
    from server.domain import TourGraph
    from server.services.container import Services

log = logging.getLogger(__name__)

SOURCES_EVERY_S = 5.0
"""Seconds between two listings of the recordings for the Timeline's dropdown."""


def _assign(handle: Any, value: object) -> None:
    """``handle.value = value`` (viser's setter, which also runs the handle's callbacks)."""
    handle.value = value


class Dashboard:
    """The viser dashboard of one server. ``start()`` serves it; ``stop()`` ends it.

    ``port`` 0 picks any free port; when the requested port is busy viser silently takes the
    next one, which :meth:`start` detects, warns about and reports in ``port``.
    ``household``: show and control only that household's robots, tours and recordings
    (``None``: all). ``logout``: a link to log out, shown beside the household's name (the
    gate's).
    """

    def __init__(
        self,
        services: Services,
        *,
        household: int | None = None,
        logout: str | None = None,
        host: str = "127.0.0.1",
        port: int = 8080,
        refresh_hz: float = 5.0,
    ) -> None:
        self.services = services
        self.household = household
        self.logout = logout
        self.actor = (
            "dashboard"
            if household is None
            else f"household:{services.repo.household(household).name}"
        )
        self.host = host
        self.requested_port = port
        self.port = port
        self.refresh_hz = refresh_hz
        self.server: viser.ViserServer | None = None
        self.controls: Controls | None = None
        self.publisher = Publisher(
            services,
            selection=self._selection,
            household=household,
            sink=self._render,
            hz=refresh_hz,
        )
        self.timeline = Timeline(
            services, household=household, selected=self._robot, image=self._image
        )
        self._scene: GraphScene | None = None
        self._layout: tuple[tuple[object, ...], GraphLayout] | None = None
        self._sent: dict[str, object] = {}
        self._step_key: tuple[object, ...] | None = None
        self._live_map: tuple[object, ...] | None = None  # the graph the live view's map shows
        self._bound_seen: tuple[str | None, int | None] | None = None
        self._task_seen: int | None = None
        self._chosen = False  # the robot in the selector was picked by a user
        self._assigning = False
        self._sources_at = -1e9
        self._question: tuple[str, int] | None = None  # (robot, id) the buttons answer
        self._drive_lock = threading.Lock()
        self._held: dict[str, dict[str, float]] = {}  # robot -> arrow -> last hold (monotonic)
        self._drivers: dict[str, int] = {}  # robot -> the client (browser) holding its arrows
        self._drive_said: dict[str, str] = {}  # robot -> the last refusal shown

    # --- lifecycle ------------------------------------------------------------------------

    def start(self) -> int:
        """Serve the dashboard and start publishing; returns the port actually used."""
        if self.server is not None:
            return self.port
        server = viser.ViserServer(host=self.host, port=self.requested_port, verbose=False)
        self.server = server
        self.port = server.get_port()
        if self.requested_port not in (0, self.port):
            message = (
                f"dashboard port {self.requested_port} is busy; the dashboard is on port "
                f"{self.port} instead (choose one with --dashboard-port, 0 = any free port)"
            )
            warnings.warn(message, RuntimeWarning, stacklevel=2)
            log.warning(message)
        self.controls = self._build_gui(server)
        self.publisher.start()
        return self.port

    def stop(self) -> None:
        """Stop publishing and serving (idempotent)."""
        self.publisher.stop()
        self.timeline.close()
        if self.server is not None:
            self.server.stop()
            self.server = None

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}"

    def refresh(self, timeout_s: float = 5.0) -> Snapshot | None:
        """Publish a fresh snapshot now (robot and tour lists re-read) and return it; waits for
        the publisher thread when it runs."""
        self.publisher.refresh_lists()
        self._sources_at = -1e9
        if self.publisher.running:
            before = self.publisher.published
            self.publisher.poke()
            self.publisher.wait_published(before, timeout_s)
            return self.publisher.latest
        return self.publisher.publish_once()

    # --- selection (read from the handles) ------------------------------------------------

    def _selection(self) -> tuple[str | None, int | None]:
        """The robot a user picked (none yet: the publisher shows a busy one) and the tour."""
        c = self.controls
        if c is None:
            return None, None
        robot = c.robot.value if c.robot.value != NONE and self._chosen else None
        return robot, tour_id_of(c.tour.value)

    def _robot(self) -> str | None:
        c = self.controls
        return None if c is None or c.robot.value == NONE else c.robot.value

    def _picked(self) -> None:
        if not self._assigning:
            self._chosen = True
        self.publisher.poke()

    def _learned(self, tour_id: int | None) -> list[schemas.LearnedChange]:
        """The tour's learned changes, when it is this dashboard's household's."""
        if tour_id is None:
            return []
        try:
            if self.household is None:
                rows = self.services.repo.learned_changes(tour_id)
                return [change_public(r) for r in rows]
            return self.services.questions.changes(tour_id, self.household)
        except DomainError:
            return []

    def _image(self, image_id: int) -> bytes | None:
        """A stored image's JPEG, when it is this dashboard's household's."""
        owner = None if self.household is None else self.services.repo.image_household(image_id)
        if self.household is not None and owner != self.household:
            return None
        return self.publisher.image(image_id)

    # --- GUI ------------------------------------------------------------------------------

    def _build_gui(self, server: viser.ViserServer) -> Controls:
        line = None
        if self.household is not None:
            name = self.actor.removeprefix("household:")
            link = f" · [Log out]({self.logout})" if self.logout else ""
            line = f"Household **{name}**{link}"
        limits = self.services.control.params
        controls = build_panels(server, household_line=line, max_v=limits.max_v, max_w=limits.max_w)
        self.timeline.build(server, controls.panel)
        controls.robot.on_update(lambda _: self._picked())
        controls.tour.on_update(lambda _: self.publisher.poke())
        controls.go.on_click(self._on_go)
        controls.stop.on_click(self._on_stop)
        controls.teach_start.on_click(self._on_teach)
        for name, arrow in controls.arrows.items():
            self._bind_arrow(arrow, name)
        server.on_client_disconnect(lambda client: self._client_gone(client.client_id))
        controls.mark.on_click(self._on_mark)
        controls.finish.on_click(self._on_finish)
        controls.abort.on_click(self._on_abort)
        controls.yes.on_click(lambda event: self._on_answer(event, "yes"))
        controls.no.on_click(lambda event: self._on_answer(event, "no"))
        server.on_client_connect(lambda _: self.publisher.poke())
        return controls

    # --- actions (the same service calls as the REST routes) ------------------------------

    def _act(
        self,
        event: viser.GuiEvent[Any],
        what: str,
        call: Callable[[str], str],
    ) -> None:
        """Run ``call(robot)`` when the robot is this dashboard's to control; show its success
        text or the error message; write the attempt to the audit log."""
        c = self.controls
        if c is None:
            return
        robot = c.robot.value
        if robot == NONE:
            self._say(event, f"{what}: no robot selected - register one with POST /robots", True)
            return
        status = 200
        try:
            self._check_owned(robot)
            done = call(robot)
        except (DomainError, ValidationError) as exc:
            status = exc.status if isinstance(exc, DomainError) else 422
            self._say(event, f"{what} refused: {error_text(exc)}", True)
        except Exception as exc:  # shown, not swallowed: the user must see that it failed
            status = 500
            log.exception("dashboard action %s failed", what)
            self._say(event, f"{what} failed: {error_text(exc)}", True)
        else:
            self._say(event, done, False)
        finally:
            self._audit(what, robot, status)
            self.publisher.refresh_lists()
            self.publisher.poke()

    def _check_owned(self, robot: str) -> None:
        """Raise :class:`NotFound` unless ``robot`` belongs to this dashboard's household (any
        robot does with ``household=None``): the same answer as for a robot that does not
        exist, as the API gives for another household's robot."""
        if self.household is None:
            return
        if self.services.repo.robot_household(robot) != self.household:
            raise NotFound(f"no robot named {robot!r} in this household")

    def _audit(self, what: str, robot: str, status: int) -> None:
        try:
            self.services.repo.add_audit(
                actor=self.actor,
                action=f"dashboard {what.lower()}",
                target=robot,
                status=status,
                address=None,
            )
        except DomainError as exc:  # a read-only or full disk: the action stands
            log.warning("audit entry for dashboard %s not written: %s", what, exc.message)

    def _say(self, event: viser.GuiEvent[Any], text: str, error: bool) -> None:
        c = self.controls
        if c is not None:
            c.message.content = ("**Error:** " if error else "") + inert(text)
        if event.client is not None:
            event.client.add_notification(
                "Refused" if error else "Done",
                text,
                color="red" if error else "green",
                auto_close_seconds=10.0 if error else 4.0,
            )

    def _on_go(self, event: viser.GuiEvent[Any]) -> None:
        c = self.controls
        assert c is not None
        goal, tour = c.goal.value, tour_id_of(c.tour.value)

        def call(robot: str) -> str:
            if goal == NONE:
                raise DomainError("no place to go to: teach a tour first, then pick a goal")
            record = True if c.record.value else None
            task = self.services.navigation.goto(
                robot, schemas.GotoRequest(location=goal, tour=tour, record=record)
            )
            return f"{robot}: task {task.id} to **{task.goal}** is {task.state}"

        self._act(event, "Go", call)

    def _on_stop(self, event: viser.GuiEvent[Any]) -> None:
        def call(robot: str) -> str:
            with self._drive_lock:
                self._held.pop(robot, None)
            stopped = self.services.control.halt(robot)
            if not stopped:
                raise Conflict(
                    f"robot {robot!r} has no navigation underway; nothing to stop (nobody "
                    "drives it and it is not turning at a place)"
                )
            return f"{robot}: stopped {', '.join(stopped)}"

        self._act(event, "Stop", call)

    def _on_teach(self, event: viser.GuiEvent[Any]) -> None:
        """Start teaching the tour named in "Tour to teach" (created when new) or, with no
        name, the tour chosen above."""
        c = self.controls
        assert c is not None
        name, chosen = c.teach_tour.value.strip(), tour_id_of(c.tour.value)

        def call(robot: str) -> str:
            household = self.services.repo.robot_household(robot)
            if household is None:
                raise NotFound(f"no robot named {robot!r}")
            if name:
                known = {t.name: t.id for t in self.services.tours.list(household)}
                tour_id = known.get(name)
                if tour_id is None:
                    body = schemas.TourCreate(name=name)
                    tour_id = self.services.tours.create(body, household).id
            elif chosen is not None:
                tour_id = chosen
            else:
                raise DomainError("name the tour to teach (a new name creates it)")
            state = self.services.teaching.start(robot, schemas.TeachStart(tour=tour_id))
            return (
                f"{robot}: teaching *{state.tour_name}*: name the place where it stands, then "
                "drive it to the next one"
            )

        self._act(event, "Start teaching", call)

    # --- driving by hand (web/drive.py) -----------------------------------------------------

    def _bind_arrow(self, arrow: viser.GuiButtonHandle, direction: str) -> None:
        def hold(event: viser.GuiEvent[Any]) -> None:
            self._on_hold(event, direction)

        def release(event: viser.GuiEvent[Any]) -> None:
            self._on_release(event, direction)

        arrow.on_hold(hold, callback_hz=DRIVE_HZ)
        arrow.on_click(release)

    def _on_hold(self, event: viser.GuiEvent[Any], direction: str) -> None:
        """An arrow is held (repeated ``DRIVE_HZ`` times a second): drive while it is."""
        robot = self._robot()
        if robot is None:
            return
        with self._drive_lock:
            held = self._held.setdefault(robot, {})
            held[direction] = time.monotonic()
            if event.client_id is not None:
                self._drivers[robot] = event.client_id
        self._drive(event, robot)

    def _on_release(self, event: viser.GuiEvent[Any], direction: str) -> None:
        """An arrow was released (a click ends every hold): stop at once, or drive on with
        the arrows still held."""
        robot = self._robot()
        if robot is None:
            return
        with self._drive_lock:
            self._held.get(robot, {}).pop(direction, None)
        self._drive(event, robot)

    def _client_gone(self, client_id: int) -> None:
        """A browser went away: the robots it was driving stop now (not after the hold's
        time-to-live)."""
        with self._drive_lock:
            robots = [r for r, c in self._drivers.items() if c == client_id]
            for robot in robots:
                self._held.pop(robot, None)
                self._drivers.pop(robot, None)
        for robot in robots:
            self._drive(None, robot)

    def _drive(self, event: viser.GuiEvent[Any] | None, robot: str) -> None:
        """Tell the control service what the held arrows say (a refusal is shown once, not at
        every repeat)."""
        c = self.controls
        if c is None:
            return
        now = time.monotonic()
        with self._drive_lock:
            held = self._held.get(robot, {})
            for name in [n for n, at in held.items() if now - at > HOLD_TTL_S]:
                del held[name]
            v, w = drive_command(set(held), speed=float(c.speed.value), turn=float(c.turn.value))
        try:
            self._check_owned(robot)
            body = schemas.TeleopCommand(v=v, w=w, ttl_s=HOLD_TTL_S)
            self.services.control.teleop(robot, body, actor=self.actor)
        except (DomainError, ValidationError) as exc:
            if v == 0 and w == 0:
                return  # a release of a drive that was refused: nothing to say again
            text = f"Drive refused: {error_text(exc)}"
            if self._drive_said.get(robot) != text and event is not None:
                self._drive_said[robot] = text
                self._say(event, text, True)
            return
        self._drive_said.pop(robot, None)
        if v == 0 and w == 0:
            self.publisher.poke()

    def _on_mark(self, event: viser.GuiEvent[Any]) -> None:
        c = self.controls
        assert c is not None
        name = c.place_name.value.strip()  # the API refuses names with spaces at either end

        def call(robot: str) -> str:
            result = self.services.teaching.mark(robot, schemas.LocationMark(name=name))
            made = "new place" if result.created else "known place"
            edge = "" if result.edge is None else f", closing a path of {result.edge.image_count}"
            return f"{robot}: marked {made} **{result.location.name}**{edge}"

        self._act(event, "Mark", call)

    def _on_finish(self, event: viser.GuiEvent[Any]) -> None:
        def call(robot: str) -> str:
            ended = self.services.teaching.finish(robot)
            tour = ended.tour
            return (
                f"{robot}: finished teaching *{tour.name}*: {len(tour.locations)} places, "
                f"{len(tour.edges)} paths"
            )

        self._act(event, "Finish", call)

    def _on_abort(self, event: viser.GuiEvent[Any]) -> None:
        def call(robot: str) -> str:
            ended = self.services.teaching.abort(robot)
            return (
                f"{robot}: teaching aborted; {ended.discarded_images} images of the open "
                "path discarded"
            )

        self._act(event, "Abort", call)

    def _on_answer(self, event: viser.GuiEvent[Any], answer: Literal["yes", "no"]) -> None:
        shown = self._question

        def call(robot: str) -> str:
            if shown is None or shown[0] != robot:
                raise DomainError(f"robot {robot!r} has asked nothing to answer")
            done = self.services.questions.answer(
                robot, shown[1], schemas.QuestionAnswer(answer=answer)
            )
            change = "" if done.change is None else f" (learned change #{done.change})"
            return f'{robot}: answered {answer} to "{done.text}"{change}'

        self._act(event, "Yes" if answer == "yes" else "No", call)

    def _questions(self, robot: str | None) -> list[schemas.QuestionPublic]:
        """The robot's open questions, when it is this dashboard's household's."""
        if robot is None:
            return []
        try:
            self._check_owned(robot)
            return self.services.questions.open_questions(robot)
        except DomainError:
            return []

    # --- rendering (publisher thread only) ------------------------------------------------

    def _put(self, key: str, handle: Any, attr: str, value: object) -> None:
        """Assign ``handle.attr = value`` only when it changed (each assignment is a message)."""
        if self._sent.get(key) == value:
            return
        setattr(handle, attr, value)
        self._sent[key] = value

    def _put_markdown(self, key: str, handle: viser.GuiMarkdownHandle, text: str) -> None:
        """Show ``text`` in a markdown handle, made :func:`inert` (only when it changed)."""
        self._put(key, handle, "content", inert(text))

    def _render(self, snap: Snapshot) -> None:
        server, c = self.server, self.controls
        if server is None or c is None:
            return
        # selectors first: setting a dropdown's options may change its value (and fire a poke)
        self._put("robot.options", c.robot, "options", snap.robots or (NONE,))
        if snap.robot is not None and c.robot.value != snap.robot:
            self._assigning = True
            try:
                _assign(c.robot, snap.robot)
            finally:
                self._assigning = False
        labels = tuple(tour_label(i, n) for i, n in snap.tours) or (NONE,)
        self._put("tour.options", c.tour, "options", labels)
        bound = (snap.robot, snap.tour_id if snap.bound else None)
        if snap.tour_id is not None and (
            (snap.bound and bound != self._bound_seen) or tour_id_of(c.tour.value) is None
        ):
            _assign(c.tour, tour_label(snap.tour_id, snap.tour_name or ""))
        self._bound_seen = bound
        graph = snap.graph
        names = tuple(loc.name for loc in graph.locations) if graph is not None else ()
        self._put("goal.options", c.goal, "options", names or (NONE,))
        if snap.task is not None and snap.task.id != self._task_seen:
            self._task_seen = snap.task.id
            if snap.task.goal in names:
                _assign(c.goal, snap.task.goal)

        # prepare everything before talking to viser
        status = status_text(snap)
        if snap.graph is not None:
            status += "\n\n" + distinctiveness_text(snap.graph)
        self._put_markdown("status", c.status, status)
        self._put_markdown("teaching", c.teaching, teaching_text(snap))
        asked = self._questions(snap.robot)
        self._question = None if not asked else (asked[0].robot, asked[0].id)
        self._put_markdown("question", c.question, questions_text(asked))
        self._put("question.visible.yes", c.yes, "visible", bool(asked))
        self._put("question.visible.no", c.no, "visible", bool(asked))
        teaching = snap.teaching is not None
        for k, handle in enumerate(c.teach_inputs):
            self._put(f"teach.visible.{k}", handle, "visible", teaching)
        for k, handle in enumerate(c.teach_starters):
            self._put(f"teach.start.visible.{k}", handle, "visible", not teaching)
        control = snap.control
        spinning = (
            control is not None and control.spin is not None and (control.spin.state == "spinning")
        )
        drivable = (
            control is not None and control.connected and snap.mode != "navigating" and not spinning
        )
        for k, control_handle in enumerate(c.drive_inputs):
            self._put(f"drive.visible.{k}", control_handle, "visible", drivable)
        self._put_markdown("drive", c.drive_note, drive_text(control, snap.mode))
        scene = self._scene
        if scene is None or scene.key != snap.graph_key:
            if scene is not None:
                scene.remove()
            scene = self._scene = GraphScene.build(server, graph, snap.graph_key)
            self._step_key = None  # redraw the belief on the new scene
        scene.show(server, snap)
        self._render_step(snap)
        now = time.monotonic()
        if now - self._sources_at >= SOURCES_EVERY_S:
            self._sources_at = now
            self.timeline.refresh_sources()
            self._put_markdown("learned", c.learned, learned_text(self._learned(snap.tour_id)))

    def _render_step(self, snap: Snapshot) -> None:
        c = self.controls
        assert c is not None
        step, graph = snap.step, snap.graph
        task = None if snap.task is None else (snap.task.id, snap.task.state)
        key: tuple[object, ...] = (
            snap.robot,
            snap.graph_key,
            task,
            None if step is None else (step.index, step.timestamp),
        )
        live = None if snap.live is None else (snap.live.wall, snap.live.command.behaviour)
        if step is None or snap.teaching is not None:
            key = (*key, live)
        if key == self._step_key:
            return
        self._step_key = key
        if snap.live is not None and (step is None or graph is None or snap.teaching):
            self._render_live(snap)
            return
        self._live_map = None
        the_map = self._map(snap)
        if step is None or graph is None:
            waiting = "no navigation frames yet" if snap.robot else "no robot registered"
            c.images.image = side_by_side(None, None, ("camera", "best match"))
            c.target.image = captioned(None, "target image", height=120)
            c.map.image = the_map
            self._put_markdown("action", c.action, f"*{waiting}*")
            self._put_markdown("votes", c.votes, "")
            self._put_markdown(
                "plots", c.plots_note, "*The belief plots appear with the first frame of a task.*"
            )
            for k, handle in enumerate(c.plots):
                self._put(f"plots.visible.{k}", handle, "visible", False)
            return
        camera = decode_rgb(step.jpeg)
        best = None
        best_caption = "best match: -"
        if step.best_image is not None:
            best = decode_rgb(self.publisher.image(int(graph.image_ids[step.best_image])))
            sim = "" if step.best_similarity is None else f" ({step.best_similarity:.2f})"
            best_caption = f"best: {graph.state_name(step.best_state)}{sim}"
        target = None
        target_caption = "target image: none"
        if step.target_image is not None:
            target = decode_rgb(self.publisher.image(int(graph.image_ids[step.target_image])))
            target_caption = f"target image #{int(graph.image_ids[step.target_image])}"
        images = side_by_side(camera, best, (f"camera  t={step.timestamp:.1f} s", best_caption))
        target_img = captioned(target, target_caption, height=120)
        action_md = action_text(step, graph) + step_lines(graph, step.path)
        votes_md = votes_text(step.votes)
        along = along_edge_data(step, graph)
        over = over_time_data(
            snap.history_t, snap.history_top, snap.history_entropy, graph.n_states
        )
        strip = behaviour_strip(snap.timeline)
        server = self.server
        assert server is not None
        with server.atomic():
            c.images.image = images
            c.target.image = target_img
            c.map.image = the_map
            self._put("live.strip", c.strip, "visible", True)
            self._put("live.target", c.target, "visible", True)
            self._put_markdown("action", c.action, action_md)
            c.strip.image = strip
            self._put_markdown("votes", c.votes, votes_md)
            self._put_markdown("plots", c.plots_note, "")
            self._put("plots.visible.2", c.over_time, "visible", True)
            self._put("plots.visible.0", c.along_label, "visible", along is not None)
            self._put("plots.visible.1", c.along_edge, "visible", along is not None)
            if along is not None:
                title, data = along
                self._put_markdown("along.label", c.along_label, f"Active path: **{title}**")
                c.along_edge.data = data
            c.over_time.data = over

    def _render_live(self, snap: Snapshot) -> None:
        """The camera outside navigation (teaching, or idle before any task): the robot's
        latest frame and the command it was given. The map (no position to show) is sent
        again only when the graph changed, not with every frame."""
        c = self.controls
        assert c is not None and snap.live is not None
        the_map = None
        if self._live_map != snap.graph_key:
            self._live_map = snap.graph_key
            the_map = self._map(snap)
        live = snap.live
        camera = decode_rgb(live.jpeg)
        kept = "kept" if live.kept else "not kept"
        place, caption = None, "no place named yet"
        at = None if snap.teaching is None else snap.teaching.current_location
        if snap.teaching is None:
            caption = "not teaching"
        elif at is not None and snap.graph is not None:
            views = [loc.image_ids for loc in snap.graph.locations if loc.name == at]
            caption = f"{at}: no image yet"
            if views and views[0]:
                place = decode_rgb(self.publisher.image(int(views[0][0])))
                caption = f"the path starts at {at}"
        images = side_by_side(camera, place, (f"camera  t={live.timestamp:.1f} s, {kept}", caption))
        server = self.server
        assert server is not None
        with server.atomic():
            c.images.image = images
            if the_map is not None:
                c.map.image = the_map
            self._put("live.strip", c.strip, "visible", False)
            self._put("live.target", c.target, "visible", False)
            self._put_markdown("action", c.action, live_text(snap))
            self._put_markdown("votes", c.votes, "")
            self._put_markdown(
                "plots", c.plots_note, "*The belief plots appear with the first frame of a task.*"
            )
            for k, handle in enumerate(c.plots):
                self._put(f"plots.visible.{k}", handle, "visible", False)

    def _map(self, snap: Snapshot) -> Any:
        """The top-down map of the snapshot's tour with the robot's most likely position."""
        graph = snap.graph
        if graph is None or graph.n_locations == 0:
            return placeholder("no tour yet", width=MAP_SIZE[0], height=MAP_SIZE[1])
        layout = self._graph_layout(snap.graph_key, graph)
        step = snap.step
        position = states = None
        if step is not None and len(step.state_belief) == graph.n_states:
            states = step.state_belief
            position = fine_position(layout, graph, int(step.fine_belief.argmax()))
        goal = None if snap.task is None or snap.task.state != "underway" else snap.task.goal
        tracked = None
        if step is not None and step.path is not None and step.path.edge < graph.n_edges:
            est = step.path
            at = tracked_position(layout, graph, est.edge, est.index, est.lateral_m)
            tracked = Tracked(est.edge, at, est.sigma_lateral, est.locked)
        return top_down(
            graph,
            layout,
            states=states,
            position=position,
            goal=goal,
            tracked=tracked,
        )

    def _graph_layout(self, key: tuple[object, ...], graph: TourGraph) -> GraphLayout:
        if self._scene is not None and self._scene.key == key and self._scene.layout is not None:
            return self._scene.layout
        if self._layout is None or self._layout[0] != key:
            self._layout = (key, graph_layout(graph))
        return self._layout[1]
