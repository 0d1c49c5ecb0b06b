"""aibo-gym: a simulated Aibo on a beacon field, for learning action and sensor models.

Importing this package registers ``AiboBeacons-v0`` with Gymnasium (idempotently).
The simulator never imports ``learners``.
"""

from __future__ import annotations

__version__ = "0.1.0"

ENV_ID = "AiboBeacons-v0"


def _register() -> None:
    from gymnasium.envs.registration import register, registry

    if ENV_ID not in registry:
        register(id=ENV_ID, entry_point="aibo_gym.envs.aibo_beacons:AiboBeaconsEnv")


_register()
