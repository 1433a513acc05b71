"""The MSTA student as a LeRobot policy: msta's own transformer behind LeRobot's interface.

:class:`MSTAPolicy` holds exactly one module, ``model``: a
:class:`msta.policies.msta.MSTATransformer`, the module msta's own ``MSTAPolicy`` holds under the
same name, so both write the same ``model.*`` tensors to ``model.safetensors`` (the
converters in :mod:`lerobot_policy_msta.convert` only move files' statistics around).

Data path: LeRobot's preprocessor turns each sample of a dataset batch into its T-step
window ``(B, T, D)`` with ``observation.state_is_pad`` (steps before the episode start repeat
its first frame, as msta's ``WindowDataset`` does: :mod:`lerobot_policy_msta.history`, from
the dataset lerobot-train builds the policy for) and z-scores ``observation.state``
(``processor_msta``). The policy cuts the state into its sensors
and turns the z-scores into bin indices with msta's own binning
(``msta.policies.msta.MSTAProcessor`` on statistics mean 0, std 1, i.e. on values already
z-scored), then runs the transformer with msta's token removal (``mask_ratio``) in training.
At inference ``select_action`` keeps the last T states per robot, padded with the first
one after ``reset()``, as msta's ``msta.policies.actor.StudentActor`` does.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Self

import torch
import torch.nn.functional as F
from lerobot.policies.pretrained import PreTrainedPolicy
from lerobot.utils.constants import ACTION, OBS_STATE
from torch import Tensor

from lerobot_policy_msta.configuration_msta import MSTAConfig
from lerobot_policy_msta.history import STATE_PAD, attach
from msta.data import sensors
from msta.data.msta_json import dataset_robot
from msta.policies.msta import MSTAInputs, MSTAProcessor, MSTATransformer
from msta.train.optim import parameter_groups


def identity_binner(config: MSTAConfig) -> MSTAProcessor:
    """msta's processor on mean 0 / std 1 statistics: it bins values that LeRobot's
    normalizer has already z-scored, exactly as msta bins its own z-scores."""
    stats = {sensors.get(n).column: {"mean": [0.0] * sensors.get(n).dim,
                                     "std": [1.0] * sensors.get(n).dim}
             for n in config.input_sensors if not sensors.get(n).binary}
    return MSTAProcessor(config.input_sensors, stats, num_bins=config.num_bins,
                         clip_std=config.clip_std, normalize_action=False)


class MSTAPolicy(PreTrainedPolicy):
    """Masked Sensory-Temporal Attention student for LeRobot (``--policy.type=msta``).

    Args:
        config: an :class:`MSTAConfig` whose features hold ``observation.state``.
        dataset_stats: unused (normalization is the processors'); lerobot passes it.
        dataset_meta: the dataset lerobot-train trains on (its ``make_policy`` passes it): its
            windows are registered for the preprocessor (:func:`~.history.attach`), and its
            robot becomes the config's ``robots`` (what msta-eval and msta-correct check).

    Building it sets torch's CPU threads to ``config.cpu_threads()``.
    """

    config_class = MSTAConfig
    name = "msta"
    config: MSTAConfig

    def __init__(self, config: MSTAConfig, dataset_stats: Any = None,
                 dataset_meta: Any = None) -> None:
        super().__init__(config)
        config.validate_features()
        torch.set_num_threads(config.cpu_threads())
        if dataset_meta is not None:
            attach(dataset_meta.root, config.state_sensors, config.history)
            config.robots = (dataset_robot(dataset_meta.root),)  # as msta-train records it
        self.model = MSTATransformer(config.to_native())
        self.binner = identity_binner(config)
        offsets, start = {}, 0
        for name in config.state_sensors:
            offsets[name] = (start, start + sensors.get(name).dim)
            start += sensors.get(name).dim
        #: input sensor -> its channels' (start, stop) in observation.state
        self.slices = {name: offsets[name] for name in config.input_sensors}
        self._window: Tensor | None = None
        self._pad: Tensor | None = None

    @classmethod
    def from_pretrained(cls, pretrained_name_or_path: str | Path, *, strict: bool = True,
                        **kwargs: Any) -> Self:
        """LeRobot's loader, strict by default: a missing or extra tensor is an error (a
        native msta checkpoint's ``model.safetensors`` loads as is)."""
        return super().from_pretrained(pretrained_name_or_path, strict=strict, **kwargs)

    # --- inputs --------------------------------------------------------------------------
    def model_inputs(self, state: Tensor, pad: Tensor | None) -> MSTAInputs:
        """z-scored state windows -> the transformer's bin indices.

        Args:
            state: ``(B, T, D)`` normalized ``observation.state`` (``(B, D)``: T = 1).
            pad: ``(B, T)`` bool, True where the step lies before the episode start, or None.
        """
        if state.dim() == 2:
            state = state[:, None]  # (B, 1, D)
        windows: dict[str, Tensor] = {n: state[..., a:b] for n, (a, b) in self.slices.items()}
        if pad is not None:
            windows["pad"] = pad.bool()
        return self.binner.discretize(windows)

    def predict(self, state: Tensor, pad: Tensor | None) -> Tensor:
        """Normalized action (B, A) for z-scored windows (mask ratio: the config's in
        training mode, 0 in eval mode)."""
        mask = self.config.mask_ratio if self.training else 0.0
        return self.model(self.model_inputs(state, pad), mask)

    # --- LeRobot's interface -------------------------------------------------------------
    def forward(self, batch: dict[str, Tensor], reduction: str = "mean"
                ) -> tuple[Tensor, dict[str, float]]:
        """Behaviour-cloning loss: MSE between the predicted and the (normalized) target
        action, msta-train's loss.

        Args:
            batch: preprocessed: ``observation.state`` (B, T, D), ``observation.state_is_pad``
                (B, T), ``action`` (B, A).
            reduction: ``mean`` (a scalar) or ``none`` (per sample, for lerobot's weighting).
        """
        if ACTION not in batch:
            raise KeyError(f"batch has no target {ACTION!r}; keys: {sorted(batch)}")
        if batch[OBS_STATE].dim() != 3 and self.config.history > 1:
            raise ValueError(
                f"{OBS_STATE} has shape {tuple(batch[OBS_STATE].shape)}: msta trains on "
                f"T-step windows (B, T, D); run the batch through the policy's preprocessor "
                "(its msta_history_processor step makes them; a checkpoint saved before that "
                "step existed lacks it: convert it to msta's format and back with "
                "python -m lerobot_policy_msta.convert)")
        pred = self.predict(batch[OBS_STATE], batch.get(STATE_PAD))  # (B, A)
        err = F.mse_loss(pred, batch[ACTION].float(), reduction="none").mean(-1)  # (B,)
        if reduction == "none":
            return err, {}
        if reduction != "mean":
            raise ValueError(f"reduction must be 'mean' or 'none', got {reduction!r}")
        return err.mean(), {}

    @torch.no_grad()
    def predict_action_chunk(self, batch: dict[str, Tensor], **kwargs: Any) -> Tensor:
        """(B, 1, A): one normalized action for the window(s) in ``batch`` (no history kept)."""
        return self.predict(batch[OBS_STATE], batch.get(STATE_PAD))[:, None]

    @torch.no_grad()
    def select_action(self, batch: dict[str, Tensor], **kwargs: Any) -> Tensor:
        """(B, A) normalized action for this step's ``observation.state`` (B, D); the last T
        states of every robot since :meth:`reset` form its window."""
        state = batch[OBS_STATE]  # (B, D)
        if state.dim() != 2:
            raise ValueError(f"select_action takes one step, {OBS_STATE} (B, D); got shape "
                             f"{tuple(state.shape)}")
        T = self.config.history
        if self._window is None or self._window.shape[0] != state.shape[0]:
            self._window = state[:, None].repeat(1, T, 1)  # (B, T, D): the first frame
            self._pad = torch.ones(state.shape[0], T, dtype=torch.bool, device=state.device)
            self._pad[:, -1] = False
        else:
            self._window = torch.cat([self._window[:, 1:], state[:, None]], dim=1)
            self._pad = torch.cat([self._pad[:, 1:], self._pad.new_zeros(state.shape[0], 1)],
                                  dim=1)
        return self.predict(self._window, self._pad)

    def reset(self) -> None:
        """Forget the history (called by lerobot-eval when the envs reset)."""
        self._window = self._pad = None

    def get_optim_params(self) -> list[dict[str, Any]]:
        """msta-train's parameter groups (``msta.train.optim.parameter_groups``): weight decay on
        matrices, none on biases, norms, embedding tables and tokens."""
        return parameter_groups(self, self.config.optimizer_weight_decay)
