"""The MSTA student: config, processor and model. Importing the package registers only the
config (``--policy.type=msta``, no torch); the model and processor load on first use of their
names (PEP 562), which registers the policy."""

import importlib
from typing import Any

from msta.policies.msta.configuration_msta import PRESETS, MSTAConfig

#: name -> module that defines it, imported on first access
_LAZY = {
    "MSTAPolicy": "msta.policies.msta.modeling_msta",
    "MSTATransformer": "msta.policies.msta.modeling_msta",
    "MSTAInputs": "msta.policies.msta.processor_msta",
    "MSTAProcessor": "msta.policies.msta.processor_msta",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["PRESETS", "MSTAConfig", "MSTAInputs", "MSTAPolicy", "MSTAProcessor", "MSTATransformer"]
