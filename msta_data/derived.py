"""Columns derived from the sensor columns, so stock LeRobot policies train on msta data.

lerobot's policies read the robot's state from one column, ``observation.state``, and ACT
and diffusion (lerobot 0.6.1, ``validate_features``) also insist on an image or an
``observation.environment_state``. An msta dataset (schema 2) therefore also holds:

* ``observation.state``: the student sensors it records, concatenated in registry order
  (the paper's 49 proprioceptive scalars for a full dataset; extension sensors such as
  ``height_map`` stay in their own columns), channel names
  ``<sensor>.<channel>`` (``joint_pos.FL_hip``, ..., ``command.vx``, ...);
* ``observation.environment_state``: the velocity command (``command.vx``, ``command.vy``,
  ``command.wz``), a copy of the command channels of ``observation.state``.

Why the command: it is the one student input that describes what the world asks of the
robot rather than the robot's own body, and it adds no information a student lacks. The
privileged signals (terrain height scan, true velocities, dynamics) are *not* used: lerobot
makes every ``observation.*`` column a policy input, so putting them there would train every
stock policy as a privileged teacher, not as a student baseline (they stay under
``privileged.*``). A dataset recorded without the ``command`` sensor has no environment
state, and ACT then refuses it with lerobot's own message.

The per-sensor columns stay the source of truth: the writer computes both columns from
them (a collector never supplies them), their statistics are the per-sensor statistics
concatenated (per-channel statistics do not depend on the other channels, so this equals
computing them over the concatenated values), and msta's own readers never read them.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np

from msta.data import sensors as registry

#: lerobot's robot-state column (``lerobot.utils.constants.OBS_STATE``).
STATE_COLUMN = "observation.state"
#: lerobot's environment-state column (``lerobot.utils.constants.OBS_ENV_STATE``).
ENV_STATE_COLUMN = "observation.environment_state"
#: Registry sensors copied into the environment state.
ENV_STATE_SENSORS: tuple[str, ...] = ("command",)
#: Every derived column, in the order they follow the sensor columns.
COLUMNS: tuple[str, ...] = (STATE_COLUMN, ENV_STATE_COLUMN)


def sources(columns: Iterable[str]) -> dict[str, list[str]]:
    """Derived column -> its source sensor columns (in order) for the columns a dataset has.

    Args:
        columns: the dataset's column names (e.g. its features dict); only registry sensor
            columns matter.

    Returns:
        one entry per derived column that has at least one source among ``columns``.
    """
    present = set(columns)
    state = [s.column for s in registry.SENSORS.values()  # the paper's inputs, no extensions
             if s.is_student_input and not s.extension and s.column in present]
    env = [registry.get(n).column for n in ENV_STATE_SENSORS if registry.get(n).column in present]
    return {col: srcs for col, srcs in ((STATE_COLUMN, state), (ENV_STATE_COLUMN, env)) if srcs}


def features(columns: Iterable[str]) -> dict[str, dict[str, Any]]:
    """The lerobot features of the derived columns for a dataset's sensor columns.

    Args:
        columns: the dataset's column names (see :func:`sources`).

    Returns:
        column -> {"dtype": "float32", "shape": (dim,), "names": ["<sensor>.<channel>", ...]}.
    """
    by_column = {s.column: s for s in registry.SENSORS.values()}
    out: dict[str, dict[str, Any]] = {}
    for col, srcs in sources(columns).items():
        names = [f"{by_column[c].name}.{ch}" for c in srcs for ch in by_column[c].names]
        out[col] = {"dtype": "float32", "shape": (len(names),), "names": names}
    return out


def derive(columns: dict[str, np.ndarray], dataset_columns: Iterable[str]
           ) -> dict[str, np.ndarray]:
    """The derived columns of one episode, for those the dataset has.

    Args:
        columns: the episode's sensor columns, ``(L, dim)`` float32 each.
        dataset_columns: the dataset's column names; a derived column absent from them (a
            dataset written before schema 2) is not produced.

    Returns:
        derived column -> ``(L, dim)`` float32, the sources concatenated along channels.
    """
    names = set(dataset_columns)
    return {col: np.concatenate([columns[s] for s in srcs], axis=1)
            for col, srcs in sources(names).items() if col in names}


def derive_stats(stats: dict[str, dict[str, np.ndarray]], dataset_columns: Iterable[str]
                 ) -> dict[str, dict[str, np.ndarray]]:
    """Statistics of the derived columns: the sources' per-channel statistics concatenated.

    Args:
        stats: per-column statistics (:mod:`msta.data.stats` format) of the sources.
        dataset_columns: the dataset's column names (as :func:`derive`).

    Returns:
        derived column -> stat name -> array (``count`` is the sources' common count).
    """
    names = set(dataset_columns)
    out = {}
    for col, srcs in sources(names).items():
        if col not in names:
            continue
        parts = [stats[s] for s in srcs]
        out[col] = {key: (np.array(parts[0][key]) if key == "count"
                          else np.concatenate([p[key] for p in parts]))
                    for key in parts[0]}
    return out
