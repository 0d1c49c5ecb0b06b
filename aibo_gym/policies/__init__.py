"""Exploration policies for collecting logs."""

from .localizer import EKFLocalizer
from .random_balanced import RandomBalancedPolicy

POLICIES = {"random-balanced": RandomBalancedPolicy}

__all__ = ["EKFLocalizer", "POLICIES", "RandomBalancedPolicy"]
