"""The student's T-step windows in lerobot-train, gathered from msta's in-memory reader.

LeRobot's dataset builds a policy's history from ``delta_timestamps``, and it windows every
``observation.*`` column alike (a policy config has no per-column setting): on an msta dataset
(nine ``observation.*`` columns) that is nine Arrow queries per sample, ~40 ms, about 0.7 s
per batch of 16, over ten times msta-train's whole step. The msta policy therefore asks
LeRobot for one frame per sample (``MSTAConfig.observation_delta_indices`` is None, ~0.3 ms)
and :class:`HistoryProcessorStep`, a step of its preprocessor before the normalizer, replaces
each sample's ``observation.state`` by the T-step window ending at it, gathered in one numpy
call from :class:`DatasetWindows` (msta's ``WindowDataset`` of the same dataset, the reader
msta-train uses): ``(B, D)`` -> ``(B, T, D)`` plus ``observation.state_is_pad``, the steps
before the episode start repeating its first frame, as LeRobot's windows do.

Which dataset: the one lerobot-train builds the policy for. ``make_policy`` hands the
dataset's metadata to ``MSTAPolicy``, which registers it here (:func:`attach`); the step,
saved with the checkpoint, holds only T, so a preprocessor loaded from a checkpoint (resume,
fine-tuning on another dataset) finds the dataset of this run. Every batch is checked: the
window's last step must equal the batch's own ``observation.state``, bit for bit, or the step
raises (a wrong dataset or index never trains silently).

The step acts only on dataset batches: those with an ``index`` and one state per sample.
Windows already there ``(B, T, D)`` and observations from an environment (no ``index``;
``select_action`` keeps its own history) pass through unchanged.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from lerobot.configs import PipelineFeatureType, PolicyFeature
from lerobot.processor import EnvTransition, ProcessorStep, ProcessorStepRegistry, TransitionKey
from lerobot.utils.constants import OBS_STATE
from torch import Tensor

from msta.data import sensors
from msta.data.windows import WindowDataset, load_episode_table

#: lerobot's pad flags of a windowed feature (``LeRobotDataset`` with delta timestamps).
STATE_PAD = f"{OBS_STATE}_is_pad"
#: The registry name of :class:`HistoryProcessorStep` in ``policy_preprocessor.json``.
STEP_NAME = "msta_history_processor"


class DatasetWindows:
    """Raw ``observation.state`` windows of a dataset by LeRobot's frame ``index``, from
    msta's ``WindowDataset`` of the sensors the state concatenates (loaded on first use).

    Args:
        root: the dataset root (``LeRobotDatasetMetadata.root``).
        state_sensors: the sensors ``observation.state`` concatenates, in order.
        history: T, the window length.
    """

    def __init__(self, root: str | Path, state_sensors: Sequence[str], history: int) -> None:
        self.root = Path(root)
        self.state_sensors = tuple(state_sensors)
        self.history = int(history)
        self.dim = sensors.total_dim(self.state_sensors)
        self._reader: WindowDataset | None = None
        self._row_of: np.ndarray | None = None

    @property
    def key(self) -> tuple[Path, tuple[str, ...], int]:
        return self.root.resolve(), self.state_sensors, self.history

    def _load(self) -> tuple[WindowDataset, np.ndarray]:
        if self._reader is None or self._row_of is None:
            reader = WindowDataset(self.root, self.state_sensors, self.history,
                                   extra_columns=())
            table = load_episode_table(self.root).set_index("episode_index").loc[
                list(reader.episodes)]
            lo = table["dataset_from_index"].to_numpy(np.int64)
            hi = table["dataset_to_index"].to_numpy(np.int64)
            row_of = np.full(int(hi.max(initial=0)), -1, np.int64)  # LeRobot index -> row
            for a, b, start in zip(lo, hi, reader.starts, strict=True):
                row_of[a:b] = np.arange(start, start + b - a)
            self._reader, self._row_of = reader, row_of
        return self._reader, self._row_of

    def gather(self, index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(B, T, D)`` float32 windows ending at the frames ``index`` (LeRobot's ``index``
        column) and their ``(B, T)`` pad flags.

        Raises:
            IndexError: an index the dataset does not hold.
        """
        reader, row_of = self._load()
        index = np.asarray(index, np.int64).reshape(-1)
        rows = np.where((index >= 0) & (index < len(row_of)),
                        row_of[np.clip(index, 0, max(len(row_of) - 1, 0))], -1)
        if (rows < 0).any():
            bad = int(index[np.argmax(rows < 0)])
            raise IndexError(f"{self.root}: no frame with index {bad}")
        return reader.windows(rows)  # the reader holds exactly the state sensors, in order


#: Datasets of the policies built for training in this process, the newest last.
_ATTACHED: list[DatasetWindows] = []


def attach(root: str | Path, state_sensors: Sequence[str], history: int) -> DatasetWindows:
    """Register the dataset a policy is built to train on (``MSTAPolicy`` does, when
    lerobot's ``make_policy`` passes ``dataset_meta``); loaded on first use.

    Args:
        root: the dataset root.
        state_sensors: the sensors ``observation.state`` concatenates.
        history: the policy's T.
    """
    new = DatasetWindows(root, state_sensors, history)
    for old in list(_ATTACHED):
        if old.key == new.key:
            _ATTACHED.remove(old)
            new = old
    _ATTACHED.append(new)
    return new


@ProcessorStepRegistry.register(name=STEP_NAME)
@dataclass
class HistoryProcessorStep(ProcessorStep):
    """Replace a dataset batch's ``observation.state`` ``(B, D)`` by its T-step windows
    ``(B, T, D)`` and add ``observation.state_is_pad`` (module docstring).

    Args:
        history: T, the window length.
    """

    history: int = 15

    def __call__(self, transition: EnvTransition) -> EnvTransition:
        obs = transition.get(TransitionKey.OBSERVATION) or {}
        extra = transition.get(TransitionKey.COMPLEMENTARY_DATA) or {}
        state = obs.get(OBS_STATE)
        if not isinstance(state, Tensor) or state.dim() != 2 or "index" not in extra:
            return transition
        windows, pad = self.windows_for(state, torch.as_tensor(extra["index"]))
        out = transition.copy()
        out[TransitionKey.OBSERVATION] = {**obs, OBS_STATE: windows}
        out[TransitionKey.COMPLEMENTARY_DATA] = {**extra, STATE_PAD: pad}
        return out

    def windows_for(self, state: Tensor, index: Tensor) -> tuple[Tensor, Tensor]:
        """The windows of the newest attached dataset of this T and width whose frames
        ``index`` are ``state``; a one-line error when there is none."""
        idx = index.detach().cpu().numpy()
        tried = []
        for source in reversed(_ATTACHED):
            if source.history != self.history or source.dim != state.shape[-1]:
                continue
            try:
                raw, pad = source.gather(idx)
            except IndexError:
                tried.append(str(source.root))
                continue
            windows = torch.from_numpy(raw).to(state.device)
            if torch.equal(windows[:, -1], state):
                return windows, torch.from_numpy(pad).to(state.device)
            tried.append(str(source.root))
        if tried:
            raise ValueError(f"{STEP_NAME}: this batch's {OBS_STATE} is not the frames its "
                             f"'index' names in the dataset the policy was built for "
                             f"({', '.join(tried)})")
        raise ValueError(
            f"{STEP_NAME}: a dataset batch (it has 'index') with one {OBS_STATE} per sample, "
            f"but no dataset is attached for T = {self.history}: build MSTAPolicy with "
            "dataset_meta=<the dataset's LeRobotDatasetMetadata> (lerobot-train does), or "
            f"load windows (B, T, D) with delta_timestamps")

    def get_config(self) -> dict[str, Any]:
        return {"history": self.history}

    def transform_features(self, features: dict[PipelineFeatureType, dict[str, PolicyFeature]]
                           ) -> dict[PipelineFeatureType, dict[str, PolicyFeature]]:
        return features  # per-frame features are unchanged; the window is the time axis
