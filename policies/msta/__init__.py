"""The MSTA student: config, processor and model (importing registers the name "msta")."""

from policies.msta.configuration_msta import PRESETS, MSTAConfig
from policies.msta.modeling_msta import MSTAPolicy, MSTATransformer
from policies.msta.processor_msta import MSTAInputs, MSTAProcessor

__all__ = ["PRESETS", "MSTAConfig", "MSTAInputs", "MSTAPolicy", "MSTAProcessor", "MSTATransformer"]
