"""Hierarchical POMDP belief tracker (001 Sections 3 and 6): model, update, smoother."""

from server.belief.model import (
    Action,
    ActionKind,
    BeliefModel,
    TransitionOperator,
    TransitionParams,
    build_model,
    expected_advance,
)
from server.belief.smoother import FixedLagSmoother, SmoothedTrajectory
from server.belief.tracker import (
    BeliefError,
    BeliefSummary,
    InvalidLikelihoodError,
    Tracker,
    TrackerMemory,
    TrackerParams,
    ZeroLikelihoodError,
    fine_likelihood,
    predict,
    summarise,
    update,
)

__all__ = [
    "Action",
    "ActionKind",
    "BeliefError",
    "BeliefModel",
    "BeliefSummary",
    "FixedLagSmoother",
    "InvalidLikelihoodError",
    "SmoothedTrajectory",
    "Tracker",
    "TrackerMemory",
    "TrackerParams",
    "TransitionOperator",
    "TransitionParams",
    "ZeroLikelihoodError",
    "build_model",
    "expected_advance",
    "fine_likelihood",
    "predict",
    "summarise",
    "update",
]
