"""msta-guard: fit the sensor guard (policies/guard.py) on fault-free episodes of a dataset,
calibrate its thresholds, save it next to a student, and measure it offline with injected
faults (docs/faults.md, "The guard").

Fitting is training (it reads a dataset and writes arrays into a checkpoint), hence here
and not in policies/, which holds only the run-time detector.

    msta-guard fit --dataset=DATA --output_dir=CHECKPOINT
    msta-guard evaluate --dataset=DATA --output_dir=CHECKPOINT   # the docs' table
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from msta.data.cli import parse_config
from msta.policies.guard import (
    CONTACT_INPUTS,
    CONTACTS,
    INPUT_SENSORS,
    NJ,
    GuardConfig,
    P,
    SensorGuard,
    encoder_partner,
    statistic_layout,
)
from msta.policies.guard_file import save_guard
from msta.train.guard_data import Episodes, load_episodes, stream
from msta.train.guard_eval import evaluate_guard, format_table


def _rows(data: Episodes) -> np.ndarray:
    """Stacked inputs ``x_t, x_{t-1}, x_{t-2}`` of every valid step: (rows, 3 D); the
    lags repeat the first frame at an episode's start (as the guard does after reset)."""
    x = np.concatenate([data[s] for s in INPUT_SENSORS], axis=2)  # (E, T, D)
    lag1 = np.concatenate([x[:, :1], x[:, :-1]], axis=1)
    lag2 = np.concatenate([lag1[:, :1], lag1[:, :-1]], axis=1)
    valid = np.arange(x.shape[1])[None] < data["length"][:, None]
    return np.concatenate([x, lag1, lag2], axis=2)[valid]


def fit_predictors(data: Episodes, ridge: float, dt: float = 0.02,
                   two_sided: bool = False) -> dict[str, np.ndarray]:
    """Ridge predictor of each physical channel from the other channels (its own joint
    encoder left out) and the residual scales: every array but ``threshold``. With
    ``two_sided`` also the predictor of each channel's previous reading from every input
    at t, t-1, t-2 but that reading (``weight2``, ``bias2``, ``z2_std``)."""
    feats = _rows(data)
    d = feats.shape[1] // 3
    mean, std = feats.mean(0), feats.std(0) + 1e-6
    f = (feats - mean) / std
    gram = f.T @ f
    own = np.zeros((P, d), bool)
    own[np.arange(P), np.arange(P)] = True
    own[np.arange(P), encoder_partner(np.arange(P))] = True
    weight, bias, resid = _ridge(f, gram, feats[:, :P], np.tile(own, 3), ridge)
    q, qd = feats[:, :NJ], feats[:, NJ:2 * NJ]
    q1, qd1 = feats[:, d:d + NJ], feats[:, d + NJ:d + 2 * NJ]
    enc = q - q1 - dt * (qd + qd1) / 2
    out = {"feat_mean": mean, "feat_std": std, "weight": weight, "bias": bias,
           "z_std": resid.std(0) + 1e-9, "enc_std": enc.std(0) + 1e-9}
    if two_sided:
        self_lag1 = np.zeros((P, 3 * d), bool)
        self_lag1[np.arange(P), d + np.arange(P)] = True
        out["weight2"], out["bias2"], resid2 = _ridge(f, gram, feats[:, d:d + P], self_lag1,
                                                      ridge)
        out["z2_std"] = resid2.std(0) + 1e-9
    return out


def contact_rows(data: Episodes, lags: int) -> tuple[np.ndarray, np.ndarray]:
    """The contact network's features and targets of every valid step: the other inputs at
    t, t-1, ..., t - lags + 1 (newest first; the first frame repeated before an episode's
    start, as the guard does after reset) and the contacts at t - 1: ``(rows, lags x 45)``,
    ``(rows, 4)``."""
    x = np.concatenate([data[s] for s in INPUT_SENSORS], axis=2)  # (E, T, D)
    lagged = [np.concatenate([np.repeat(x[:, :1], k, 1), x[:, :x.shape[1] - k]], 1)
              for k in range(lags)]
    feats = np.concatenate([v[..., CONTACT_INPUTS] for v in lagged], axis=2)
    before = np.concatenate([x[:, :1], x[:, :-1]], 1)[..., CONTACTS]
    valid = np.arange(x.shape[1])[None] < data["length"][:, None]
    return feats[valid], before[valid]


def fit_contact_model(data: Episodes, cfg: GuardConfig, seed: int = 0,
                      batch: int = 512) -> dict[str, np.ndarray]:
    """The contact network's arrays (the ``contact_*`` of ``msta.policies.guard.array_shapes``): two hidden GELU
    layers of ``cfg.contact_hidden``, logistic outputs, fitted by AdamW (lr 3e-3, cosine
    decay) on binary cross-entropy for ``cfg.contact_epochs`` passes (at least 200 steps);
    seeded."""
    import torch  # lazy: torch (~1.3 s) only to fit the contact model; the guard itself is numpy

    feats, target = contact_rows(data, cfg.contact_lags)
    mean, std = feats.mean(0), feats.std(0) + 1e-6
    gen = torch.Generator().manual_seed(seed)
    h, nn = cfg.contact_hidden, torch.nn
    with torch.random.fork_rng():  # seeded initial weights, the caller's generator untouched
        torch.manual_seed(seed)
        net = nn.Sequential(nn.Linear(feats.shape[1], h), nn.GELU(approximate="tanh"),
                            nn.Linear(h, h), nn.GELU(approximate="tanh"),
                            nn.Linear(h, len(CONTACTS)))
    x = torch.tensor((feats - mean) / std, dtype=torch.float32)
    y = torch.tensor(target > 0.5, dtype=torch.float32)
    # at least 200 steps: a few recorded episodes are too few rows for epochs to count
    steps = int(np.ceil(max(cfg.contact_epochs * len(x), 200 * batch) / batch))
    opt = torch.optim.AdamW(net.parameters(), lr=3e-3, weight_decay=1e-4)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
    for _ in range(steps):
        i = torch.randint(0, len(x), (min(batch, len(x)),), generator=gen)
        loss = torch.nn.functional.binary_cross_entropy_with_logits(net(x[i]), y[i])
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
    lin = [m for m in net if isinstance(m, nn.Linear)]
    out = {"contact_mean": mean, "contact_std": std}
    for k, m in enumerate(lin):
        out[f"contact_w{k}"] = m.weight.detach().double().numpy().T.copy()
        out[f"contact_b{k}"] = m.bias.detach().double().numpy().copy()
    out["contact_w0"][std < 1e-5] = 0.0  # an input that never varied: its weights never trained
    return out


def _ridge(f: np.ndarray, gram: np.ndarray, target: np.ndarray, drop: np.ndarray,
           ridge: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ridge fit of each target column from the standardized features ``f`` but those
    ``drop[c]`` excludes: ``(weight (F, C), bias (C,), residuals (rows, C))``."""
    cross = f.T @ target
    weight = np.zeros((f.shape[1], target.shape[1]))
    for c in range(target.shape[1]):
        keep = np.flatnonzero(~drop[c])
        a = gram[np.ix_(keep, keep)] + ridge * np.eye(len(keep))
        weight[keep, c] = np.linalg.solve(a, cross[keep, c])
    bias = target.mean(0)  # features are centred
    return weight, bias, target - f @ weight - bias


def calibrate(cfg: GuardConfig, arrays: dict[str, np.ndarray], data: Episodes,
              dt: float = 0.02) -> np.ndarray:
    """Thresholds: margin x each statistic's largest value on ``data`` (fault-free; margin2
    for ``z2_sq``, contact_margin for ``contact``), no lower than ``min_repeat`` steps for
    repeats and ``binary_tolerance`` for contacts."""
    inf = np.full(len(statistic_layout(cfg.two_sided, cfg.contact_model)[0]), np.inf)
    probe = SensorGuard(cfg, {**arrays, "threshold": inf}, num_envs=len(data["length"]), dt=dt)
    peak = stream(probe, data)["max_stat"]
    kind = np.array([n.split(":")[0] for n in probe.names])
    margin = np.full(len(peak), cfg.margin)
    margin[kind == "z2_sq"] = cfg.margin2
    margin[kind == "contact"] = cfg.contact_margin
    thr = margin * peak
    thr[kind == "repeat"] = np.maximum(peak[kind == "repeat"] + 1, cfg.min_repeat)
    thr[kind == "binary"] = np.maximum(thr[kind == "binary"], cfg.binary_tolerance)
    return thr


def fit_guard(dataset_root: str | Path, episodes: list[int] | None = None,
              cfg: GuardConfig | None = None, dt: float = 0.02) -> SensorGuard:
    """A guard fitted and calibrated on fault-free ``episodes`` of a dataset (None: all).

    The predictors (about 5,000 weights) and the thresholds use the same episodes: on
    100,000+ steps a ridge fit's in-sample residuals match held-out ones, and the
    thresholds are set by the rarest fault-free events, so they want every episode there
    is (calibrating on a 30 % split instead doubled the held-out false alarms).

    Args:
        dataset_root: a dataset written by msta-collect / msta-correct.
        episodes: the episodes to use (hold out the ones you evaluate on).
        cfg: decision settings (default GuardConfig()).
        dt: control period (s).
    """
    cfg = cfg or GuardConfig()
    if episodes is not None and not len(episodes):
        raise ValueError("fit_guard needs at least one episode")
    data = load_episodes(dataset_root, None if episodes is None else sorted(episodes))
    if data["length"].max() <= cfg.warmup + cfg.window:
        raise ValueError(f"fit_guard needs episodes longer than warmup + window "
                         f"({cfg.warmup + cfg.window} steps) to calibrate on; the longest has "
                         f"{int(data['length'].max())}")
    arrays = fit_predictors(data, cfg.ridge, dt, cfg.two_sided)
    if cfg.contact_model:
        arrays |= fit_contact_model(data, cfg)
    arrays["threshold"] = calibrate(cfg, arrays, data, dt)
    return SensorGuard(cfg, arrays, dt=dt)


@dataclass
class GuardCommand:
    """msta-guard: fit the sensor guard on a dataset's fault-free episodes and save it into
    a checkpoint folder (fit), or measure it with injected faults (evaluate).

    Args:
        command: ``fit`` (writes guard.json and guard.safetensors into output_dir) or
            ``evaluate`` (fits on all but the held-out episodes, prints the detection and
            false-alarm table; writes guard_eval.json into output_dir).
        dataset: dataset root whose fault-free episodes fit and calibrate the guard.
        output_dir: checkpoint folder the guard is saved into (usually the student's).
        val_fraction: share of episodes held out for ``evaluate`` (``fit`` uses them all).
        seed: seed of the held-out split and of the injected faults.
        min_length: ``evaluate`` injects faults only into held-out episodes this long (steps).
        guard: the guard's decision settings (``--guard.margin``, ``--guard.window``, ...).
    """

    command: str = "fit"
    dataset: str = ""
    output_dir: str = ""
    val_fraction: float = 0.2
    seed: int = 0
    min_length: int = 300
    guard: GuardConfig = field(default_factory=GuardConfig)


def run(cmd: GuardCommand) -> dict:
    if cmd.command not in ("fit", "evaluate"):
        raise ValueError(f"command must be fit or evaluate, got {cmd.command!r}")
    if not cmd.dataset or not cmd.output_dir:
        raise ValueError("--dataset and --output_dir are required")
    cfg = cmd.guard
    if cmd.command == "fit":
        guard = fit_guard(cmd.dataset, cfg=cfg)
        path = save_guard(guard, cmd.output_dir)
        print(f"msta-guard: saved {path}")
        return {"path": str(path)}

    from msta.data.windows import episode_split  # lazy: pandas after parsing (--help)

    train_eps, held = episode_split(cmd.dataset, cmd.val_fraction, cmd.seed)
    guard = fit_guard(cmd.dataset, train_eps, cfg=cfg)
    report = evaluate_guard(guard, cmd.dataset, held, seed=cmd.seed, min_length=cmd.min_length)
    save_guard(guard, cmd.output_dir)
    (Path(cmd.output_dir) / "guard_eval.json").write_text(json.dumps(report, indent=1) + "\n")
    print(format_table(report))
    return report


def main(argv: list[str] | None = None) -> None:
    """Console entry point (``msta-guard``)."""
    cmd = parse_config(GuardCommand, argv, "msta-guard", positionals=("command",))
    try:
        run(cmd)
    except (KeyError, ValueError, FileNotFoundError) as e:
        msg = e.args[0] if isinstance(e, KeyError) and e.args else e
        print(f"msta-guard: error: {msg}", file=sys.stderr)
        raise SystemExit(2) from None


if __name__ == "__main__":
    main()
