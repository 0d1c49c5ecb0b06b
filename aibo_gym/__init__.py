"""aibo-gym: a simulated Aibo on a beacon field, for learning action and sensor models.

Importing this package registers ``AiboBeacons-v0`` with Gymnasium (idempotently), with
``max_episode_steps`` = the default config ``max_steps`` (27000), so ``gym.make`` adds a
``TimeLimit`` and ``env.spec.max_episode_steps`` is set. In processes that do not import this
package (``SubprocVecEnv`` workers, async vector envs), use the id ``"aibo_gym:AiboBeacons-v0"``.
It also registers ``WheeledRobot-v0`` (a velocity-commanded robot with a range/bearing camera,
:mod:`aibo_gym.envs.wheeled_robot`), with its own default ``max_steps`` (6000).
The simulator never imports ``learners``.
"""

from __future__ import annotations

__version__ = "0.1.0"

ENV_ID = "AiboBeacons-v0"
WHEELED_ENV_ID = "WheeledRobot-v0"


def _register() -> None:
    from gymnasium.envs.registration import register, registry

    from . import wheeled_config
    from .config import default_config

    if ENV_ID not in registry:
        register(
            id=ENV_ID,
            entry_point="aibo_gym.envs.aibo_beacons:AiboBeaconsEnv",
            max_episode_steps=default_config()["max_steps"],
        )
    if WHEELED_ENV_ID not in registry:
        register(
            id=WHEELED_ENV_ID,
            entry_point="aibo_gym.envs.wheeled_robot:WheeledRobotEnv",
            max_episode_steps=wheeled_config.default_config()["max_steps"],
        )


_register()

# The simulator twins of the effect catalogue register themselves in ``effects.EFFECTS`` on import: here, in the
# package's own init, so the registry is full whoever imports what.
from . import catalogue  # noqa: E402,F401
