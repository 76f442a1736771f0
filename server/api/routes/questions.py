"""Questions the robot asks a person, and their answers (docs/learning.md)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path
from starlette.concurrency import run_in_threadpool

from server import schemas
from server.api.deps import RobotDep, ServicesDep

router = APIRouter(prefix="/robots/{robot}/questions", tags=["questions"])
QuestionId = Annotated[int, Path(ge=1, le=schemas.MAX_ID, description="Question id.")]


@router.get("", response_model=list[schemas.QuestionPublic])
def open_questions(robot: RobotDep, services: ServicesDep) -> list[schemas.QuestionPublic]:
    """The robot's questions waiting for an answer ("are we at the kitchen?" while teaching,
    "keep this new path?" after exploring), oldest first; each expires at ``expires_at``."""
    return services.questions.open_questions(robot)


@router.post(
    "/{question_id}",
    response_model=schemas.QuestionPublic,
    responses={
        404: {"model": schemas.ErrorBody, "description": "No such question of this robot."},
        409: {"model": schemas.ErrorBody, "description": "Already answered or withdrawn."},
        410: {"model": schemas.ErrorBody, "description": "Expired: too late to answer."},
    },
)
async def answer_question(
    question_id: QuestionId, body: schemas.QuestionAnswer, robot: RobotDep, services: ServicesDep
) -> schemas.QuestionPublic:
    """Answer 'yes' or 'no'. Yes to 'same_place' closes the taught path at that place (a loop
    closure); no marks the two views as look-alikes. Yes to 'new_path' adds the found path as
    an edge; no discards it. Each change is listed (and undone) at /tours/{tour}/learned."""
    return await run_in_threadpool(services.questions.answer, robot, question_id, body)
