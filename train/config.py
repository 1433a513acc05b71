"""The optimizer / schedule / logging flags every training loop shares (stage 1 and 2)."""

from __future__ import annotations

from dataclasses import dataclass, fields

from msta.data.checks import check_at_least, check_number

#: The largest ``batch_size``: 65,536 windows of T = 15 steps of the 49 student input
#: channels are 190 MB of float32, and the model's activations several times that.
MAX_BATCH_SIZE = 65_536

#: ``--optimizer`` choices (train/optim.py builds them).
OPTIMIZERS = ("adamw", "muon")


#: The stage-2 training mask ratio when ``--mask_ratio`` is not given (the paper's; stage 1
#: trains at the policy config's ratio, 0.75 for MSTA).
STAGE2_MASK_RATIO = 0.5
#: The test-time mask ratios a masked student's stage-2 rollouts drive at, spread over its
#: robots: half with every token, half at the stage-2 ratio, so the rounds label the states
#: a test at 50 % reaches (the recipe of the demo, the study and the device check).
STAGE2_ROLLOUT_MASK_RATIOS: tuple[float, ...] = (0.0, STAGE2_MASK_RATIO)


def training_mask_ratio(requested: float | None, policy_ratio: float, stage: int = 1) -> float:
    """The token-removal ratio a training run uses (the one rule, both stages).

    Args:
        requested: ``--mask_ratio``; when given, it is the answer.
        policy_ratio: the ratio the student's config records, the one stage 1 trained it
            with (``--policy.mask_ratio``).
        stage: 1: ``policy_ratio``; 2: :data:`STAGE2_MASK_RATIO` capped at ``policy_ratio``,
            so a student trained without masking (a GRU) is retrained without it.
    """
    if requested is not None:
        return float(requested)
    if stage == 1:
        return float(policy_ratio)
    return min(STAGE2_MASK_RATIO, float(policy_ratio))


def check_optimizer(name: str) -> None:
    """``--optimizer``'s one check (every config that takes it)."""
    if name not in OPTIMIZERS:
        raise ValueError(f"optimizer={name!r}: choose one of {', '.join(OPTIMIZERS)}")


@dataclass
class LoopConfig:
    """Args:
        steps: optimizer steps.
        batch_size: windows per step.
        lr: peak learning rate.
        optimizer: ``adamw`` (every weight), or ``muon``: Muon on the transformer blocks'
            weight matrices and AdamW on the rest (embeddings, value tables, norms, head),
            one ``lr`` for both (Muon's update RMS matched to AdamW's); a student without
            transformer blocks (gru, rma_tcn) trains with AdamW either way.
        weight_decay: AdamW decoupled weight decay (not applied to biases, norms, embeddings).
        warmup_steps: linear warm-up from 0 to ``lr``, then cosine decay.
        min_lr_ratio: the cosine ends at ``lr * min_lr_ratio``.
        grad_clip: max global gradient norm (0 = no clipping).
        mask_ratio: training token-removal ratio; null (the default) = the policy config's
            in stage 1 (0.75 for MSTA) and 0.5 capped at it in stage 2
            (:func:`training_mask_ratio`).
        eval_every: validation every N steps (0 = only at the end).
        save_every: checkpoint every N steps (0 = only the final one).
        log_every: train metrics to CSV / TensorBoard every N steps.
        val_samples: validation windows evaluated (evenly spaced over the split).
        seed: seeds the model init, the sampler, the masks and every RNG.
        progress: show a tqdm progress bar.
        ema_decay: keep an exponential moving average of the weights (decay per step,
            e.g. 0.995: about the last 200 steps) and make it the result: the final
            validation and the final checkpoint use the averaged weights. 0 = off.
        dummy_tokens: random dummy tokens appended to every training sample after masking
            (the paper's stress test, as msta-eval's ``dummy_tokens`` scenario draws them:
            fresh each step, never trained), so the student learns to ignore distractors;
            token students (MSTA) only. Validation runs without them. 0 = none.
        sensor_dropout: probability that a training sample loses one whole physical sensor
            (joint angles, joint velocities, gyro, gravity or foot contacts, uniformly chosen)
            for its whole window, on top of the token mask, so that the student learns to
            walk with a sensor gone (msta-eval's ``sensor_removal``; a guard that removes a
            lying sensor). MSTA removes the sensor's tokens, the baselines put their
            placeholders in; validation runs without it. 0 = off.
        unmasked_share: share of the optimizer steps that train with every token (mask 0)
            instead of the training mask ratio, drawn per step from the run's seeded mask
            generator (so a resumed run draws the same): the student fits the whole input
            better and keeps most of its fit with tokens removed. 0 = every step at the mask.
        max_minutes: stop after this many minutes at the next safe point and exit with
            status 75: after an optimizer step, with a checkpoint saved (msta-correct also
            after a round's append, its retraining and its evaluation); the same command
            with ``--resume=true`` continues there. 0 = no limit (msta_data/budget.py).
    """

    steps: int = 2000
    batch_size: int = 64
    lr: float = 1e-3
    optimizer: str = "adamw"
    weight_decay: float = 0.01
    warmup_steps: int = 100
    min_lr_ratio: float = 0.1
    grad_clip: float = 1.0
    mask_ratio: float | None = None
    eval_every: int = 500
    save_every: int = 1000
    log_every: int = 10
    val_samples: int = 1024
    seed: int = 0
    progress: bool = True
    ema_decay: float = 0.0
    dummy_tokens: int = 0
    sensor_dropout: float = 0.0
    unmasked_share: float = 0.0
    max_minutes: float = 0.0

    def __post_init__(self) -> None:
        check_optimizer(self.optimizer)
        check_at_least(self, 1, "steps", "log_every", "val_samples")
        check_at_least(self, 1, "batch_size", maximum=MAX_BATCH_SIZE,
                       why="a batch's windows are gathered in memory at once")
        check_at_least(self, 0, "warmup_steps", "eval_every", "save_every", "grad_clip",
                       "weight_decay", "dummy_tokens", "max_minutes")
        check_number("lr", self.lr, 0, above=True)
        if not 0.0 <= self.ema_decay < 1.0:
            raise ValueError(f"ema_decay={self.ema_decay} must be in [0, 1)")
        if not 0.0 <= self.min_lr_ratio <= 1.0:
            raise ValueError(f"min_lr_ratio={self.min_lr_ratio} must be in [0, 1]")
        if not 0.0 <= self.sensor_dropout <= 1.0:
            raise ValueError(f"sensor_dropout={self.sensor_dropout} must be in [0, 1]")
        if not 0.0 <= self.unmasked_share <= 1.0:
            raise ValueError(f"unmasked_share={self.unmasked_share} must be in [0, 1]")
        if self.mask_ratio is not None and not 0.0 <= self.mask_ratio < 1.0:
            raise ValueError(f"mask_ratio={self.mask_ratio} must be in [0, 1)")

    def loop_part(self) -> LoopConfig:
        """Just the :class:`LoopConfig` fields (for subclasses carrying more)."""
        return LoopConfig(**{f.name: getattr(self, f.name) for f in fields(LoopConfig)})
