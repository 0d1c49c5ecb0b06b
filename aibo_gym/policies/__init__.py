"""Exploration policies for collecting logs, as specs ``{name, params}`` (:mod:`.base`).

=================  =========================================================================
name               what it does
=================  =========================================================================
random-balanced    the paper's: random, least-used safe command every 5 s (``localizer``
                   ``"truth"`` by default: the true pose, an oracle; ``"ekf"``: onboard)
uniform            a uniformly random safe command every 5 s (onboard EKF)
informed           greedy in the expected information (sightings per command, coverage)
sb3                a trained SB3 agent: ``"sb3:AGENT.zip"`` (``aibo train-explorer``)
greedy             one-step D-optimal: the largest predicted log-det gain of the onboard
                   information about the velocity table and the sensor curve
explorer           the shipped learned explorer (``aibo train-explorer``): an SB3 agent
                   seeing ``greedy``'s information state and predicted gains
=================  =========================================================================
"""

from ..config import REWARD_TERMS
from .base import POLICIES, HoldPolicy, make_policy, policy_label, register_policy, validate_policy
from .explorer import ExplorerPolicy
from .greedy import GreedyPolicy
from .informed import InformedPolicy
from .localizer import EKFLocalizer
from .onboard import OnboardTracker
from .random_balanced import RandomBalancedPolicy
from .sb3 import SB3Policy
from .uniform import UniformPolicy

register_policy(RandomBalancedPolicy)
POLICIES.update({k: POLICIES.pop(k) for k in ["random-balanced", "uniform", "informed", "sb3", "greedy", "explorer"]})  # table order

__all__ = ["EKFLocalizer", "ExplorerPolicy", "GreedyPolicy", "HoldPolicy", "InformedPolicy", "OnboardTracker", "POLICIES",
           "REWARD_TERMS", "RandomBalancedPolicy", "SB3Policy", "UniformPolicy", "make_policy", "policy_label",
           "register_policy", "validate_policy"]
