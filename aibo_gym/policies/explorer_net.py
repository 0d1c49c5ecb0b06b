"""The ``explorer`` agent's network (torch; imported only by training and by loading an agent).

:class:`PerCommandPolicy` is an SB3 ``ActorCriticPolicy`` whose logit for command a is

    skip x gain_a  +  score(gain_a, logdet_a, nominal velocity of a, the shared features)

with one small MLP ``score`` shared by the 40 commands (its last layer starts at zero, so the
untrained agent is ``greedy`` softened by ``skip``): it can learn where to depart from the one-step
gain (the state of a command's information, where the robot is, the time) with few parameters
and the same rule for every command. The value is a plain MLP of the whole observation.
"""

from __future__ import annotations

import numpy as np
import torch
from stable_baselines3.common.policies import ActorCriticPolicy
from torch import nn

from aibo_core.actions import N_ACTIONS, attempted_velocities

from .explorer import N_HEAD, N_INFO_FEATURES

SKIP_INIT = 20.0  # logit per unit of the gain feature (10 nats) at the start
HIDDEN = 32
VALUE_HIDDEN = 64


class PerCommandExtractor(nn.Module):
    """latent_pi = the 40 logits (see the module docstring), latent_vf = a 2-layer tanh MLP."""

    def __init__(self) -> None:
        super().__init__()
        self.latent_dim_pi, self.latent_dim_vf = N_ACTIONS, VALUE_HIDDEN
        att = attempted_velocities()
        self.register_buffer("command", torch.as_tensor(att / np.abs(att).max(axis=0), dtype=torch.float32))
        n_in = 2 + 3 + N_HEAD + 1
        self.score = nn.Sequential(nn.Linear(n_in, HIDDEN), nn.Tanh(), nn.Linear(HIDDEN, HIDDEN), nn.Tanh(), nn.Linear(HIDDEN, 1))
        self.skip = nn.Parameter(torch.tensor(SKIP_INIT))
        self.value = nn.Sequential(nn.Linear(N_INFO_FEATURES, VALUE_HIDDEN), nn.Tanh(),
                                   nn.Linear(VALUE_HIDDEN, VALUE_HIDDEN), nn.Tanh())

    def zero_last(self) -> None:
        nn.init.zeros_(self.score[-1].weight)
        nn.init.zeros_(self.score[-1].bias)

    def forward_actor(self, obs: torch.Tensor) -> torch.Tensor:
        logdet = obs[:, N_HEAD:N_HEAD + N_ACTIONS]
        shared = torch.cat([obs[:, :N_HEAD], obs[:, N_HEAD + N_ACTIONS:N_HEAD + N_ACTIONS + 1]], dim=1)
        gain = obs[:, N_HEAD + N_ACTIONS + 1:]
        b = obs.shape[0]
        x = torch.cat([gain[..., None], logdet[..., None], self.command.expand(b, -1, -1),
                       shared[:, None, :].expand(-1, N_ACTIONS, -1)], dim=-1)
        return self.skip * gain + self.score(x).squeeze(-1)

    def forward_critic(self, obs: torch.Tensor) -> torch.Tensor:
        return self.value(obs)

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.forward_actor(obs), self.forward_critic(obs)


class PerCommandPolicy(ActorCriticPolicy):
    """See the module docstring (the observation is used as is: no features extractor layers)."""

    def __init__(self, *args, **kwargs) -> None:
        kwargs["ortho_init"] = False
        super().__init__(*args, **kwargs)

    def _build_mlp_extractor(self) -> None:
        self.mlp_extractor = PerCommandExtractor()

    def _build(self, lr_schedule) -> None:
        super()._build(lr_schedule)
        self.action_net = nn.Identity()  # the extractor's latent is the logits
        self.mlp_extractor.zero_last()
        self.optimizer = self.optimizer_class(self.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)
