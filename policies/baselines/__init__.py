"""The paper's baselines as students (importing registers their names):
``gru``, ``rma_tcn``, ``tert_concat``, ``tert_separate``, ``tert_mask``.
MSTA's learnable-mask variant is ``msta`` with ``learnable_mask=True``. ``mlp`` (a plain MLP
on the flattened window) is a reference learner, not one of the paper's baselines."""

from policies.baselines.common import (
    TimestepConfig,
    TimestepInputs,
    TimestepPolicy,
    TimestepProcessor,
)
from policies.baselines.gru import GRUConfig, GRUPolicy
from policies.baselines.mlp import MLPConfig, MLPPolicy
from policies.baselines.tcn import TCNConfig, TCNPolicy
from policies.baselines.tert import (
    TERTConcatConfig,
    TERTConcatPolicy,
    TERTConfig,
    TERTMaskConfig,
    TERTMaskPolicy,
    TERTPolicy,
    TERTSeparateConfig,
    TERTSeparatePolicy,
)

#: registered baseline names
BASELINES: tuple[str, ...] = ("gru", "rma_tcn", "tert_concat", "tert_separate", "tert_mask")
#: registered reference learners that are not baselines of the paper
REFERENCES: tuple[str, ...] = ("mlp",)

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
