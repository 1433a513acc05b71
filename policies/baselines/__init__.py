"""The paper's baselines as students (importing registers their configs' names; the models
register on first use):
``gru``, ``rma_tcn``, ``tert_concat``, ``tert_separate``, ``tert_mask``.
MSTA's learnable-mask variant is ``msta`` with ``learnable_mask=True``. ``mlp`` (a plain MLP
on the flattened window) is a reference learner, not one of the paper's baselines.

``BASELINES`` and ``REFERENCES`` are read from the registry
(:func:`msta.policies.registry.registered_policies`), so a policy registered with
``kind="baseline"`` or ``kind="reference"`` appears in them without being named here."""

import importlib
from typing import Any

from msta.policies.baselines.configs import (
    GRUConfig,
    MLPConfig,
    TCNConfig,
    TERTConcatConfig,
    TERTConfig,
    TERTMaskConfig,
    TERTSeparateConfig,
    TimestepConfig,
)
from msta.policies.registry import registered_policies

#: module attribute -> registry kind it lists
_LISTS = {"BASELINES": "baseline", "REFERENCES": "reference"}
#: model name -> module that defines it, imported on first access (torch loads then)
_LAZY = {
    "TimestepInputs": "common", "TimestepPolicy": "common", "TimestepProcessor": "common",
    "GRUPolicy": "gru", "MLPPolicy": "mlp", "TCNPolicy": "tcn", "TERTPolicy": "tert",
    "TERTConcatPolicy": "tert", "TERTMaskPolicy": "tert", "TERTSeparatePolicy": "tert",
}


def __getattr__(name: str) -> Any:
    """``BASELINES`` (registered baseline names) and ``REFERENCES`` (registered reference
    learners that are not baselines of the paper), sorted tuples from the registry; the
    models (``GRUPolicy``, ...) from their modules."""
    if name in _LISTS:
        return tuple(registered_policies(_LISTS[name]))
    if name in _LAZY:
        return getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
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
