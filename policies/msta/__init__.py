"""The MSTA student: config, processor and model (importing registers the name "msta")."""

from msta.policies.msta.configuration_msta import PRESETS, MSTAConfig
from msta.policies.msta.modeling_msta import MSTAPolicy, MSTATransformer
from msta.policies.msta.processor_msta import MSTAInputs, MSTAProcessor

__all__ = ["PRESETS", "MSTAConfig", "MSTAInputs", "MSTAPolicy", "MSTAProcessor", "MSTATransformer"]
