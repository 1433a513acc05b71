"""``--optimizer``: which weights Muon takes, the fallback for students without transformer
blocks, and a clear error for an unknown name."""

from __future__ import annotations

import pytest
import torch

from msta.policies.baselines import GRUConfig
from msta.policies.factory import make_policy
from msta.policies.msta import MSTAConfig
from msta.train.config import LoopConfig
from msta.train.optim import MuonAdamW, make_optimizer


def stats() -> dict:
    from msta.data import features as F

    feats = F.build_features(None)
    out = {}
    for col in [*F.input_columns(feats), "action"]:
        n = feats[col]["shape"][0]
        out[col] = {"mean": [0.0] * n, "std": [1.0] * n, "min": [-1.0] * n, "max": [1.0] * n}
    return out


def test_muon_takes_the_block_matrices_and_adamw_the_rest():
    policy = make_policy(MSTAConfig.from_preset("tiny"), stats())
    opt = make_optimizer(policy, 1e-3, 0.01, "muon")
    assert isinstance(opt, MuonAdamW)
    by_id = {id(p): n for n, p in policy.named_parameters()}
    muon = {by_id[id(p)] for g in opt._muon.param_groups for p in g["params"]}
    adamw = {by_id[id(p)] for g in opt._adamw.param_groups for p in g["params"]}
    assert muon and all(".blocks." in f".{n}" and n.endswith("weight") for n in muon)
    assert not any("norm" in n or "ln" in n.split(".")[-2] for n in muon)
    assert muon | adamw == set(by_id.values()) and not muon & adamw
    assert any("embed" in n for n in adamw) and any("head" in n for n in adamw)
    # one param_groups list: a schedule scaling it scales both optimizers
    for g in opt.param_groups:
        g["lr"] = 5e-4
    assert {g["lr"] for o in (opt._muon, opt._adamw) for g in o.param_groups} == {5e-4}


def test_a_student_without_transformer_blocks_trains_with_adamw():
    policy = make_policy(GRUConfig.from_preset("cpu"), stats())
    opt = make_optimizer(policy, 1e-3, 0.01, "muon")
    assert isinstance(opt, torch.optim.AdamW)


def test_an_unknown_optimizer_is_a_one_line_error():
    with pytest.raises(ValueError, match="optimizer='sgd': choose one of adamw, muon"):
        LoopConfig(optimizer="sgd")
