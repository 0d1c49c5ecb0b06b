"""Gymnasium environments of aibo-gym."""

from .aibo_beacons import AiboBeaconsEnv
from .wheeled_robot import WheeledRobotEnv

__all__ = ["AiboBeaconsEnv", "WheeledRobotEnv"]
