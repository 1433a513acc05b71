"""The RMA teacher as an rsl_rl actor, and the conversions to and from msta's ``rma``
teacher checkpoint.

``RMAActor`` is an rsl_rl ``MLPModel`` whose latent is ``cat(mu(e_t), o_t)``: the factor
encoder mu runs on the ``privileged`` group, its output joins the ``proprio`` group, and
rsl_rl's MLP (the policy pi) maps that to the action mean; rsl_rl's Gaussian distribution
adds the exploration noise. Its ``encoder`` and ``mlp`` hold exactly the weights of
``msta.policies.teacher.rma.RMATeacher``'s ``encoder`` and ``policy`` (same layer indices), so
:func:`to_teacher` and :func:`load_from_teacher` copy them one to one.
"""

from __future__ import annotations

import torch
from rsl_rl.models import MLPModel
from tensordict import TensorDict

from msta.policies.teacher.rma import RMAConfig, RMATeacher, mlp
from msta.train.ppo_config import PPOConfig
from msta.train.rsl_env import PRIVILEGED, PROPRIO


class RMAActor(MLPModel):
    """rsl_rl actor with the RMA teacher's architecture.

    Args:
        obs, obs_groups, obs_set, output_dim: as for rsl_rl's ``MLPModel``; the set must
            list ``privileged`` and ``proprio``.
        encoder_hidden, latent_dim, policy_hidden, activation: ``RMAConfig``'s fields.
        distribution_cfg: rsl_rl's output distribution (e.g. ``GaussianDistribution``).
    """

    def __init__(self, obs: TensorDict, obs_groups: dict[str, list[str]], obs_set: str,
                 output_dim: int, encoder_hidden: tuple[int, ...] = (512, 256, 128),
                 latent_dim: int = 32, policy_hidden: tuple[int, ...] = (256, 128),
                 activation: str = "elu", distribution_cfg: dict | None = None) -> None:
        groups = obs_groups[obs_set]
        if sorted(groups) != sorted([PRIVILEGED, PROPRIO]):
            raise ValueError(f"RMAActor reads the groups {PRIVILEGED!r} and {PROPRIO!r}; "
                             f"obs_groups[{obs_set!r}] = {groups}")
        # read by _get_latent_dim during MLPModel.__init__ (plain ints, set before it)
        object.__setattr__(self, "_latent_dim", int(latent_dim))
        object.__setattr__(self, "_proprio_dim", int(obs[PROPRIO].shape[-1]))
        super().__init__(obs, obs_groups, obs_set, output_dim, hidden_dims=list(policy_hidden),
                         activation=activation, obs_normalization=False,
                         distribution_cfg=distribution_cfg)
        self.encoder = mlp([int(obs[PRIVILEGED].shape[-1]), *encoder_hidden, latent_dim],
                           activation)

    def _get_latent_dim(self) -> int:
        return self._latent_dim + self._proprio_dim

    def get_latent(self, obs: TensorDict, masks: torch.Tensor | None = None,
                   hidden_state=None) -> torch.Tensor:
        return torch.cat([self.encoder(obs[PRIVILEGED]), obs[PROPRIO]], dim=-1)

    def set_actor_frozen(self, frozen: bool) -> None:
        """Freeze the whole actor (critic warm-up), or train all of it again."""
        for p in self.parameters():
            p.requires_grad_(not frozen)

    def as_jit(self):  # rsl_rl's exports copy only ``mlp``; export the msta checkpoint instead
        raise NotImplementedError("export the teacher with msta.train.teacher.model.to_teacher")

    as_onnx = as_jit


def actor_cfg(rma: RMAConfig, init_std: float) -> dict:
    """rsl_rl ``actor`` config for an RMA teacher architecture."""
    return {"class_name": f"{RMAActor.__module__}:{RMAActor.__name__}",
            "encoder_hidden": list(rma.encoder_hidden), "latent_dim": rma.latent_dim,
            "policy_hidden": list(rma.policy_hidden), "activation": rma.activation,
            "distribution_cfg": {"class_name": "GaussianDistribution", "init_std": init_std,
                                 "std_type": "scalar"}}


def teacher_runner_cfg(ppo: PPOConfig, rma: RMAConfig) -> dict:
    """rsl_rl ``OnPolicyRunner`` train_cfg of msta-train-teacher: ``ppo``'s settings with the
    RMA actor of ``rma`` reading both observation groups (the critic too)."""
    both = [PRIVILEGED, PROPRIO]
    return ppo.runner_cfg(actor_cfg(rma, ppo.init_std), {"actor": both, "critic": both})


def to_teacher(actor: RMAActor, rma: RMAConfig) -> RMATeacher:
    """An ``rma`` teacher with the actor's weights (its deterministic action: the mean)."""
    teacher = RMATeacher(rma)
    teacher.encoder.load_state_dict(actor.encoder.state_dict())
    teacher.policy.load_state_dict(actor.mlp.state_dict())
    return teacher


def load_from_teacher(actor: RMAActor, teacher: RMATeacher) -> None:
    """Copy an ``rma`` teacher's weights into the actor (warm start); shapes must match."""
    actor.encoder.load_state_dict(teacher.encoder.state_dict())
    actor.mlp.load_state_dict(teacher.policy.state_dict())
