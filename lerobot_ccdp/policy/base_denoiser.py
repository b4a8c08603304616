"""The base network: one UNet for eps_a, eps_s and eps_h (the recovery heads' networks: `heads/`)."""

import torch
from lerobot.policies.diffusion.modeling_diffusion import DiffusionConditionalUnet1d
from torch import Tensor, nn

from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig
from lerobot_ccdp.policy.small_batch_convolutions import with_small_batch_convolutions

# Condition dropout while training (independent per condition): dropping the state and the history trains
# eps_a, dropping one trains eps_s or eps_h. The failure-set classifiers drop the state alike.
P_DROP_STATE = 0.3
P_DROP_HISTORY = 0.5


class BaseDenoiser(nn.Module):
    """LeRobot's diffusion UNet with two droppable conditions, so one network gives eps_a, eps_s and eps_h.

    The global condition is [state * keep_s, keep_s, history * keep_h, keep_h]: a dropped condition is zeroed
    and its keep flag tells the network it is absent (condition dropout, as in classifier-free guidance).
    """

    def __init__(self, config: CCDPConfig):
        super().__init__()
        self.state_cond_dim = config.n_obs_steps * config.frame_dim
        self.history_cond_dim = config.history_length * (config.frame_dim + config.action_dim)
        self.unet = with_small_batch_convolutions(
            DiffusionConditionalUnet1d(
                config, global_cond_dim=self.state_cond_dim + self.history_cond_dim + 2
            )
        )

    def forward(
        self, noisy: Tensor, timestep: Tensor, state: Tensor, keep_s: Tensor, history: Tensor, keep_h: Tensor
    ) -> Tensor:
        """noisy (R, horizon, A); state (R, state_cond_dim); history (R, history_cond_dim); keep_* (R, 1)."""
        cond = torch.cat([state * keep_s, keep_s, history * keep_h, keep_h], dim=-1)
        return self.unet(noisy, timestep, global_cond=cond)


def base_estimates(base: nn.Module, terms: list[str], state: Tensor, history: Tensor):
    """A function of (noisy sample, timestep) giving the base network's (a `BaseDenoiser`) `terms` ("a":
    eps_a, "s": eps_s, "h": eps_h) for every row, in one call with the conditions repeated once per term."""
    r, k = state.shape[0], len(terms)
    if not k or not r:
        return lambda sample, t: {}
    ones, zeros = torch.ones(r, 1, device=state.device), torch.zeros(r, 1, device=state.device)
    keep = {"a": (zeros, zeros), "s": (ones, zeros), "h": (zeros, ones)}
    state_rows, history_rows = state.repeat(k, 1), history.repeat(k, 1)
    keep_s = torch.cat([keep[term][0] for term in terms])
    keep_h = torch.cat([keep[term][1] for term in terms])

    def estimates(sample: Tensor, t: int) -> dict[str, Tensor]:
        step = torch.full((r * k,), t, dtype=torch.long, device=sample.device)
        eps = base(sample.repeat(k, 1, 1), step, state_rows, keep_s, history_rows, keep_h)
        return dict(zip(terms, eps.split(r), strict=True))

    return estimates
