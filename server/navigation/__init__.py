"""Navigation: from a frame to a motion command, as explicit behaviours and one arbiter.

* :mod:`.params` - every setting (``NavigationParams``), frozen, with documented defaults.
* :mod:`.runtime` - what is derived from one snapshot of a tour (``TourRuntime``).
* :mod:`.task` - a task's life (``Task``, ``TaskState``).
* :mod:`.observation` - one frame perceived once (``perceive`` -> ``Observation``).
* :mod:`.behaviours`, :mod:`.docking` - the behaviours, each with its own state.
* :mod:`.arbiter` - the order of precedence that picks one proposal, and obstacle avoidance.
* :mod:`.navigator` - the step: perceive -> propose -> arbitrate -> dock -> avoid -> task.

Pure: NumPy, OpenCV, SciPy and networkx through the core; no I/O, no HTTP, no storage.
"""

from server.navigation.command import BEHAVIOURS, Command, Proposal
from server.navigation.navigator import Navigator, Step
from server.navigation.observation import Frame, Observation
from server.navigation.params import ROBUST_WEIGHTS, AmbiguityParams, NavigationParams
from server.navigation.runtime import TourRuntime
from server.navigation.task import Task, TaskState

__all__ = [
    "BEHAVIOURS",
    "ROBUST_WEIGHTS",
    "AmbiguityParams",
    "Command",
    "Frame",
    "NavigationParams",
    "Navigator",
    "Observation",
    "Proposal",
    "Step",
    "Task",
    "TaskState",
    "TourRuntime",
]
