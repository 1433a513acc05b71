"""The paper's baselines as students (importing registers their names):
``gru``, ``rma_tcn``, ``tert_concat``, ``tert_separate``, ``tert_mask``.
MSTA's learnable-mask variant is ``msta`` with ``learnable_mask=True``. ``mlp`` (a plain MLP
on the flattened window) is a reference learner, not one of the paper's baselines.

``BASELINES`` and ``REFERENCES`` are read from the registry
(:func:`msta.policies.factory.registered_policies`), so a policy registered with
``kind="baseline"`` or ``kind="reference"`` appears in them without being named here."""

from typing import Any

from msta.policies.baselines.common import (
    TimestepConfig,
    TimestepInputs,
    TimestepPolicy,
    TimestepProcessor,
)
from msta.policies.baselines.gru import GRUConfig, GRUPolicy
from msta.policies.baselines.mlp import MLPConfig, MLPPolicy
from msta.policies.baselines.tcn import TCNConfig, TCNPolicy
from msta.policies.baselines.tert import (
    TERTConcatConfig,
    TERTConcatPolicy,
    TERTConfig,
    TERTMaskConfig,
    TERTMaskPolicy,
    TERTPolicy,
    TERTSeparateConfig,
    TERTSeparatePolicy,
)
from msta.policies.factory import registered_policies

#: module attribute -> registry kind it lists
_LISTS = {"BASELINES": "baseline", "REFERENCES": "reference"}


def __getattr__(name: str) -> Any:
    """``BASELINES`` (registered baseline names) and ``REFERENCES`` (registered reference
    learners that are not baselines of the paper), sorted tuples from the registry."""
    if name in _LISTS:
        return tuple(registered_policies(_LISTS[name]))
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

__all__ = [
    "BASELINES",
    "REFERENCES",
    "GRUConfig",
    "GRUPolicy",
    "MLPConfig",
    "MLPPolicy",
    "TCNConfig",
    "TCNPolicy",
    "TERTConcatConfig",
    "TERTConcatPolicy",
    "TERTConfig",
    "TERTMaskConfig",
    "TERTMaskPolicy",
    "TERTPolicy",
    "TERTSeparateConfig",
    "TERTSeparatePolicy",
    "TimestepConfig",
    "TimestepInputs",
    "TimestepPolicy",
    "TimestepProcessor",
]
