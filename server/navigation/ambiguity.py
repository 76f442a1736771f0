"""Active disambiguation in a navigation step: the policy's decision, replaced by the action
that best separates the belief's hypotheses when there are two or more
(:mod:`server.policy.disambiguation`, seed 000)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from server.belief.model import ActionKind
from server.navigation.runtime import TourRuntime
from server.policy.disambiguation import disambiguate
from server.policy.voting import Decision, plan_for


def separate(
    runtime: TourRuntime,
    belief: np.ndarray,
    decision: Decision,
    goal: int,
    *,
    hold_goal: bool,
) -> Decision:
    """``decision`` with the hypotheses it faced, and the separating action when one beats
    the voted action (:func:`server.policy.disambiguation.disambiguate`). Left alone while
    exploring or standing at the goal, and when the runtime has no view profiles."""
    if runtime.fine_profile is None or decision.action.kind in (
        ActionKind.EXPLORE,
        ActionKind.DO_NOTHING,
    ):
        return decision
    costs = runtime.costs(goal)
    plan = plan_for(runtime.graph, goal, costs, runtime.policy_params, hold_goal=hold_goal)
    found = disambiguate(
        runtime.graph,
        runtime.model,
        belief,
        plan,
        decision.action,
        costs,
        runtime.fine_profile,
        runtime.params.ambiguity.disambiguation,
        runtime.cost_params,
    )
    if found is None:
        return decision
    out = replace(decision, hypotheses=found.hypotheses.leaders, separating=found.separating)
    if not found.separating:
        return out
    action = found.action
    if action.kind is ActionKind.NAVIGATE and action.edge is not None:
        L = runtime.graph.n_locations
        lo, hi = int(plan.offsets[action.edge]), int(plan.offsets[action.edge + 1])
        best = int(np.argmax(belief[L + lo : L + hi]))
        return replace(
            out, action=action, target_image=min(best + 1, hi - lo - 1), active_edge=action.edge
        )
    return replace(out, action=action, target_image=None, active_edge=None)
