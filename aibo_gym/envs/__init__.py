"""Gymnasium environments of aibo-gym."""

from .aibo_beacons import AiboBeaconsEnv

__all__ = ["AiboBeaconsEnv"]
