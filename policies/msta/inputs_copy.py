"""A copy of an MSTA policy that reads other inputs (msta-finetune's minimized observation)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

from msta.data.sensors import get

__all__ = ["with_inputs"]


def with_inputs(policy: Any, sensors: Sequence[str], history: int,
                stats: Mapping[str, Mapping[str, Any]] | None = None) -> Any:
    """A copy that reads only ``sensors`` and trains on windows of ``history`` steps: its
    config.json and processor.json name just those inputs, so it rolls out, trains,
    evaluates and exports on them (msta-finetune's minimized observation). Every weight
    is copied except the value tables, encoders and sensor embeddings of the dropped
    sensors, so on the kept inputs the copy acts exactly as ``policy`` (in the
    learnable-mask ablation ``policy`` fills absent sensors with mask tokens; the copy
    has no tokens for the dropped ones).

    A sensor ``policy`` does not read (e.g. the ``height_map`` extension) is added after
    the kept ones with fresh weights (value tables or encoder, and its sensor
    embedding) and the normalization statistics of its column in ``stats``; until they
    are trained its tokens are noise to the transformer.

    Args:
        policy: an :class:`~msta.policies.msta.modeling_msta.MSTAPolicy`.
        sensors: registry student inputs; ``policy``'s are kept in its config order,
            new ones follow in the given order.
        history: the copy's training window T (>= 1).
        stats: dataset statistics (``column -> {"mean", "std"}``) covering every new
            non-binary sensor.
    """
    inputs = policy.config.input_sensors
    new = tuple(dict.fromkeys(s for s in sensors if s not in inputs))
    for name in new:
        if not get(name).is_student_input:
            raise ValueError(f"sensor {name!r} is privileged (teacher only), not a student "
                             "input")
    keep = tuple(s for s in inputs if s in sensors)
    config = replace(policy.config, input_sensors=(*keep, *new), history=history)
    pdict = policy.processor.to_dict()
    pstats = dict(pdict["stats"])
    for name in new:
        col = get(name).column
        if get(name).binary:
            continue
        if stats is None or col not in stats:
            raise ValueError(f"no statistics for the new input {name!r} (column {col!r}); "
                             "pass the dataset's")
        pstats[col] = {k: [float(v) for v in stats[col][k]] for k in ("mean", "std")}
    processor = type(policy.processor).from_dict(
        {**pdict, "input_sensors": list(config.input_sensors), "stats": pstats})
    copy = type(policy)(config, processor).to(policy.device)  # fresh weights for new sensors
    target = copy.state_dict()
    prefixes = ("model.sensor_embed.", "model.encoders.")
    for k, v in policy.state_dict().items():
        if k.startswith(prefixes):
            if k.split(".")[2] in keep:
                target[k] = v
        elif k != "model.bin_embed.weight":
            target[k] = v
    rows = policy.model.table_rows(keep).to(policy.device)  # kept tables come first in the copy
    table = target["model.bin_embed.weight"].clone()
    table[:len(rows)] = policy.model.bin_embed.weight.detach()[rows]
    target["model.bin_embed.weight"] = table
    copy.load_state_dict(target)
    return copy.train(policy.training)
