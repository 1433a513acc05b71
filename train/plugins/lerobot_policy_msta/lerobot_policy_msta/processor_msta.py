"""LeRobot processor pipelines of the MSTA student: the normalization msta's processor does,
as LeRobot's own steps (saved next to the weights as ``policy_preprocessor*.json`` /
``policy_postprocessor*.json`` + ``.safetensors``, as for every LeRobot policy).

Pre: rename (none) -> add batch dim -> device -> ``msta_history_processor`` (a dataset
batch's T-step windows, :mod:`lerobot_policy_msta.history`) -> ``NormalizerProcessorStep``
(z-scores of ``observation.state`` and of the action target). Post: ``UnnormalizerProcessorStep`` (the
action back to raw units) -> cpu. The statistics are msta's processor's, bit for bit
(:func:`msta_stats`): std through ``msta.policies.processor.effective_std``, ``eps=0`` (msta divides
by the std itself), and the binary channels (foot contacts) pass through unchanged (mean 0,
std 1), because msta thresholds their raw values at 0.5. Binning the z-scores into tokens is
the model's input layer (``modeling_msta``), not a normalization.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import torch
from lerobot.configs import FeatureType, PolicyFeature
from lerobot.processor import (
    AddBatchDimensionProcessorStep,
    DeviceProcessorStep,
    NormalizerProcessorStep,
    PolicyAction,
    PolicyProcessorPipeline,
    RenameObservationsProcessorStep,
    UnnormalizerProcessorStep,
)
from lerobot.processor.factory import make_policy_processor_pipelines
from lerobot.utils.constants import ACTION, OBS_STATE

from lerobot_policy_msta.configuration_msta import MSTAConfig
from lerobot_policy_msta.history import HistoryProcessorStep
from msta.data import sensors
from msta.policies.processor import effective_std, read_stats

Stats = dict[str, dict[str, torch.Tensor]]


def msta_stats(config: MSTAConfig, dataset_stats: Mapping[str, Mapping[str, Any]] | None
               ) -> Stats:
    """The normalizers' statistics: ``observation.state`` and (with ``normalize_action``) the
    action, as float32 mean / std, std 1 where below ``MIN_STD`` (``effective_std``), binary
    channels mean 0 std 1.

    Args:
        config: the policy config (``state_sensors`` gives the channel layout).
        dataset_stats: the dataset's ``meta/stats.json`` (lerobot's ``dataset.meta.stats``).

    Raises:
        KeyError: a needed column or its mean / std is missing (never skipped silently).
        ValueError: a column has the wrong size or invalid values.
    """
    if dataset_stats is None:
        raise KeyError("msta needs the dataset statistics (observation.state and action) to "
                       "build its normalizers; none were given")
    dim = sensors.total_dim(config.state_sensors)
    state = read_stats(dataset_stats, OBS_STATE, dim, f"msta's {OBS_STATE}")
    mean = torch.tensor(state["mean"], dtype=torch.float32)
    std = torch.tensor(state["std"], dtype=torch.float32)
    start = 0
    for name in config.state_sensors:
        spec = sensors.get(name)
        if spec.binary:  # thresholded raw at 0.5 by the model, as msta's processor does
            mean[start:start + spec.dim], std[start:start + spec.dim] = 0.0, 1.0
        start += spec.dim
    out: Stats = {OBS_STATE: {"mean": mean, "std": effective_std(std)}}
    if config.normalize_action:
        act = read_stats(dataset_stats, ACTION, config.action_dim, "the action target")
        out[ACTION] = {"mean": torch.tensor(act["mean"], dtype=torch.float32),
                       "std": effective_std(torch.tensor(act["std"], dtype=torch.float32))}
    return out


def make_msta_pre_post_processors(
    config: MSTAConfig,
    dataset_stats: Mapping[str, Mapping[str, Any]] | None = None,
) -> tuple[PolicyProcessorPipeline[dict[str, Any], dict[str, Any]],
           PolicyProcessorPipeline[PolicyAction, PolicyAction]]:
    """The pre- and post-processor of an MSTA policy (found by lerobot's factory by name).

    Args:
        config: the policy config.
        dataset_stats: the dataset's statistics (required: see :func:`msta_stats`).
    """
    stats = msta_stats(config, dataset_stats)
    state = PolicyFeature(FeatureType.STATE, (sensors.total_dim(config.state_sensors),))
    action = PolicyFeature(FeatureType.ACTION, (config.action_dim,))
    norm_map = config.normalization_mapping
    return make_policy_processor_pipelines(
        input_steps=[
            RenameObservationsProcessorStep(rename_map={}),
            AddBatchDimensionProcessorStep(),
            DeviceProcessorStep(device=config.device),
            HistoryProcessorStep(history=config.history),
            NormalizerProcessorStep(features={OBS_STATE: state, ACTION: action},
                                    norm_map=norm_map, stats=stats, eps=0.0),
        ],
        output_steps=[
            UnnormalizerProcessorStep(features={ACTION: action}, norm_map=norm_map,
                                      stats={k: v for k, v in stats.items() if k == ACTION},
                                      eps=0.0),
            DeviceProcessorStep(device="cpu"),
        ],
    )
