"""The robot's navigation loop: frame in, motion command out, until the task ends.

Talks only to the driver Protocols, so the same loop drives the simulated robot and a real one.
A command is obeyed for at most its time-to-live: if no newer answer has come by then, the
robot stops rather than drive on a stale command.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import httpx

from robot_client.client import ApiError, TeachRepeatClient
from robot_client.drivers.base import Camera, Clock, DepthSensor, Motors
from server import schemas
from server.imaging import encode_jpeg


@dataclass(frozen=True)
class LoopParams:
    """``period_s`` (0.1): time between frames. ``jpeg_quality`` (85). ``max_steps``: give up
    after this many frames. ``retry_s`` (0.2, doubling to ``max_retry_s`` 2.0): backoff while
    the server cannot be reached (the robot stands still meanwhile)."""

    period_s: float = 0.1
    jpeg_quality: int = 85
    max_steps: int = 3000
    retry_s: float = 0.2
    max_retry_s: float = 2.0
    max_retry_total_s: float = 60.0
    wait_for_answer: bool = False
    """Wait for the server's answer however long it takes. For a simulated robot, whose clock
    stands still while it waits (so a busy machine cannot change what it does); a real robot
    waits at most the time-to-live of the command it is driving on."""


@dataclass
class LoopOutcome:
    task: schemas.TaskPublic | None
    steps: int
    last: schemas.NavigationFrameResult | None
    actions: dict[str, int] = field(default_factory=dict)


StepHook = Callable[[int, schemas.NavigationFrameResult], None]


def drive(
    client: TeachRepeatClient,
    robot: str,
    *,
    camera: Camera,
    motors: Motors,
    clock: Clock,
    depth: DepthSensor | None = None,
    params: LoopParams = LoopParams(),
    on_step: StepHook | None = None,
) -> LoopOutcome:
    """Stream frames and obey commands until the task is no longer underway."""
    steps = 0
    last: schemas.NavigationFrameResult | None = None
    actions: dict[str, int] = {}
    retry = params.retry_s
    retried = 0.0
    # odometry counts since its last reading: start from now, so that what the wheels did
    # before this task (the end of the one before, a push by hand) is not reported as its start
    motors.odometry()
    while steps < params.max_steps:
        image = camera.read()
        if image is None:
            break
        jpeg = encode_jpeg(image, params.jpeg_quality)
        v, w = motors.odometry()
        profile = None if depth is None else [float(r) for r in depth.profile()]
        try:
            # while a command is in force, wait for the answer no longer than it stays valid
            result = client.upload_frame(
                robot,
                jpeg,
                timestamp=clock.now(),
                v=v,
                w=w,
                depth=profile,
                timeout=None if last is None or params.wait_for_answer else last.command.ttl_s,
            )
        except httpx.TransportError:
            motors.stop()  # never drive blind while the server is away
            if retried >= params.max_retry_total_s:
                raise
            clock.sleep(retry)
            retried += retry
            retry = min(retry * 2, params.max_retry_s)
            continue
        retry, retried = params.retry_s, 0.0
        if not isinstance(result, schemas.NavigationFrameResult):
            raise ApiError(409, f"the robot is {result.mode}, not navigating", "conflict")
        steps += 1
        last = result
        command = result.command
        actions[command.action] = actions.get(command.action, 0) + 1
        motors.command(command.v, command.w)
        if on_step is not None:
            on_step(steps, result)
        if result.task is None or result.task.state != "underway":
            motors.stop()
            break
        clock.sleep(min(params.period_s, command.ttl_s))
        if params.period_s > command.ttl_s:
            motors.stop()  # the command expired before the next frame is due
            clock.sleep(params.period_s - command.ttl_s)
    else:
        motors.stop()
    return LoopOutcome(
        task=None if last is None else last.task, steps=steps, last=last, actions=actions
    )
