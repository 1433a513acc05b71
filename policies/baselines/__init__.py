"""The paper's baselines as students (importing registers their names):
``gru``, ``rma_tcn``, ``tert_concat``, ``tert_separate``, ``tert_mask``.
MSTA's learnable-mask variant is ``msta`` with ``learnable_mask=True``."""

from policies.baselines.common import (
    TimestepConfig,
    TimestepInputs,
    TimestepPolicy,
    TimestepProcessor,
)
from policies.baselines.gru import GRUConfig, GRUPolicy
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

__all__ = [
    "BASELINES",
    "GRUConfig",
    "GRUPolicy",
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
