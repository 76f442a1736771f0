"""Navigation policy (001 Section 7): cost to the goal and belief-weighted voting."""

from server.policy.costs import CostParams, cost_to_goal, edge_costs, edge_remaining_s, route_graph
from server.policy.voting import Decision, PolicyParams, VotePlan, build_vote_plan, decide

__all__ = [
    "CostParams",
    "Decision",
    "PolicyParams",
    "VotePlan",
    "build_vote_plan",
    "cost_to_goal",
    "decide",
    "edge_costs",
    "edge_remaining_s",
    "route_graph",
]
