"""Masked Sensory-Temporal Attention (MSTA) student.

Every scalar (channel i of sensor a at step t) is one token:

    token = value_embed[a, i][bin] + sincos2d(i, age_t) + sensor_embed[a]        # (d,)

The value embedding is a 256-row table per sensor channel by default (``value_embedding``:
``channel``; ``sensor`` or ``shared`` tables are the ablations), initialised as a
constant-norm arc ``cos(z/2) u + sin(z/2) v`` of the bin centre's z-score z with random
directions u, v per table (``value_init``); age_t = T - 1 - t (0 = newest step), so a
longer window (T = 20 after training at T = 15) only adds older ages and the recent steps
keep their embeddings. Training removes a
random fraction α of the N tokens of every sample (kept count K = N - round(αN), equal
within the batch), appends a learnable state token <S>, runs a pre-norm transformer and
reads the 12 joint targets from <S>. Identity comes from the embeddings only, so sensors
may be supplied in any order, any subset of sensors / channels and any T work unchanged.

Padded steps (before the episode start) are removed first; if some remain because other
samples of the batch have fewer, they are hidden from attention with a key mask. Channels
removed per sample (``absent``) go the same way (:mod:`~msta.policies.msta.removal`); a traced
graph (msta-export) hides them instead (a fixed token count, the same action up to rounding).

Dummy tokens (the paper's test-time stress test, ``dummy_tokens`` = D): after masking, D
random tokens are appended to every sample before the readout tokens; they attend and are
attended to in every block like real tokens and are never masked. Each is the sum of three
parts drawn independently from the ``generator``, so every part looks like a real token's
but together they form no reading of any channel:

    dummy = value_embed[table][bin] + pos[slot] + sensor_embed[sensor]   # (d,), random present ones

Fresh ones are drawn for every sample and call; no parameter changes. ``dummy_tokens`` may
instead be a (B, D, 4) tensor of uniform numbers in [0, 1) that fixes the four draws (table,
bin, slot, sensor) of each dummy: the same observation then gives the same action, which
PPO needs when it re-evaluates its rollout (msta-finetune-ppo ``--dummy_tokens``).

Per-step attention (``attention`` = ``step``, :mod:`~msta.policies.msta.step_attention`):
the same tokens without their age, blocks that attend within one step, then readout blocks
over every token with its age added to key and value. Axial attention (``attention`` =
``axial``, :mod:`~msta.policies.msta.axial_attention`): the paper's tokens, blocks that
alternate between a step's tokens and a channel's, readout tokens over every token.

Sensor tokens (one per sensor and step, ``tokens`` = ``sensor``): :mod:`~msta.policies.msta.sensor_tokens`.

Encoded sensors (``SensorSpec.encoder_tokens`` = k > 0, e.g. the ``height_map`` extension):
each step's channels (clipped z-scores) go through a small MLP (dim -> 2d -> k·d) to k
tokens, which then are tokens like any other: position code over (token index j, age),
the sensor's type embedding, removed by the same random mask. They follow the scalar
tokens in the layout:

    token = encoder[a](z_{a,t})[j] + sincos2d(j, age_t) + sensor_embed[a]            # (d,)
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, Self

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from msta.data.sensors import get
from msta.policies.base import Absent, StudentPolicy, uniform
from msta.policies.msta.axial_attention import axial_features, token_keys
from msta.policies.msta.configuration_msta import MSTAConfig
from msta.policies.msta.dummy import draw_dummy_tokens
from msta.policies.msta.inputs_copy import with_inputs
from msta.policies.msta.processor_msta import MSTAInputs, MSTAProcessor
from msta.policies.msta.removal import (
    absent_tokens,
    additive_mask,
    complete_inputs,
    encoded_keys,
    keep_per_sample,
    num_kept,
)
from msta.policies.msta.sensor_tokens import make_encoders, sensor_embed_steps
from msta.policies.msta.step_attention import make_age_proj, step_features
from msta.policies.msta.value_tables import initial_tables
from msta.policies.processor import Batch, Channels
from msta.policies.registry import register_policy
from msta.policies.transformer import (
    init_linears,
    make_blocks,
    scale_residuals,
    sincos_2d,
)

__all__ = ["MSTAPolicy", "MSTATransformer"]


class MSTATransformer(nn.Module):
    """Bin indices of any sensor subset -> (normalized) joint targets."""

    def __init__(self, cfg: MSTAConfig) -> None:
        super().__init__()
        self.cfg = cfg
        d = cfg.dim
        #: inputs read one token per scalar (the paper's) / through an MLP encoder
        sensor_tokens = cfg.tokens == "sensor"  # every input through its own encoder
        self.scalar_sensors = () if sensor_tokens else tuple(
            n for n in cfg.input_sensors if not get(n).encoder_tokens)
        self.encoded_sensors = tuple(n for n in cfg.input_sensors if get(n).encoder_tokens)
        self.bin_embed = nn.Embedding(cfg.num_bins * self._num_tables(), d)
        self.encoders = make_encoders(cfg.input_sensors, d) if sensor_tokens else nn.ModuleDict({
            n: nn.Sequential(nn.Linear(get(n).dim, 2 * d), nn.GELU(approximate="tanh"),
                             nn.Linear(2 * d, get(n).encoder_tokens * d))
            for n in self.encoded_sensors})
        self.sensor_embed = nn.ParameterDict(
            {n: nn.Parameter(torch.zeros(d)) for n in cfg.input_sensors})
        self.state_token = nn.Parameter(torch.zeros(d))
        R = cfg.state_tokens  # <S> and R - 1 more readout tokens (1: the paper)
        self.extra_state_tokens = nn.Parameter(torch.zeros(R - 1, d)) if R > 1 else None
        self.mask_token = nn.Parameter(torch.zeros(d)) if cfg.learnable_mask else None
        self.blocks = make_blocks(cfg)
        #: ``attention`` = ``step``: each readout block's map of a token's age to its key and value
        self.age_proj = make_age_proj(cfg)
        self.ln_f = nn.LayerNorm(d)
        h = cfg.head_hidden_dim
        self.head = (nn.Sequential(nn.Linear(d * R, h), nn.GELU(approximate="tanh"),
                                   nn.Linear(h, cfg.action_dim))
                     if h else nn.Linear(d * R, cfg.action_dim))
        #: the auxiliary target's head (``aux_target``), on the same readout features
        self.aux_head = nn.Linear(d * R, get(cfg.aux_target).dim) if cfg.aux_target else None
        self._pos_cache: dict[tuple, tuple[Tensor, ...]] = {}
        self._init_weights()

    def _num_tables(self) -> int:
        if self.cfg.tokens == "sensor":  # no value tables: encoders read bin centres
            return 0
        if self.cfg.value_embedding == "sensor":
            return len(self.scalar_sensors)
        if self.cfg.value_embedding == "channel":
            return sum(get(n).dim for n in self.scalar_sensors)
        return 1

    def table_of(self, name: str, ch: Tensor) -> Tensor:
        """Value-table index of channels ``ch`` of sensor ``name`` (0 when shared)."""
        sensors_ = self.scalar_sensors
        if self.cfg.value_embedding == "channel":
            return sum(get(n).dim for n in sensors_[:sensors_.index(name)]) + ch
        if self.cfg.value_embedding == "sensor":
            return torch.full_like(ch, sensors_.index(name))
        return torch.zeros_like(ch)

    def table_rows(self, names: Sequence[str]) -> Tensor:
        """Rows of ``bin_embed`` holding the value tables of input sensors ``names``, in that
        order: (rows,). A model whose inputs are just ``names`` has exactly these tables."""
        nb = self.cfg.num_bins
        names = [n for n in names if n in self.scalar_sensors]  # encoded sensors: no table
        if not self._num_tables():
            return torch.zeros(0, dtype=torch.long)
        if self.cfg.value_embedding == "shared":
            return torch.arange(nb)
        if self.cfg.value_embedding == "sensor":
            tables = torch.tensor([self.scalar_sensors.index(n) for n in names], dtype=torch.long)
        else:
            tables = torch.cat([self.table_of(n, torch.arange(get(n).dim)) for n in names]
                               or [torch.zeros(0, dtype=torch.long)])
        return (tables[:, None] * nb + torch.arange(nb)).flatten()  # (tables * nb,)

    def _init_weights(self) -> None:
        def std(lin: nn.Linear) -> float:
            return self.cfg.init_std or 1.0 / math.sqrt(lin.in_features)

        init_linears([self], std)
        scale_residuals(self.blocks, std)  # GPT-2: residual projections scaled by depth
        with torch.no_grad():  # value tables start smooth in the bin; trained after
            if self._num_tables():  # sensor tokens: no tables to initialise
                self.bin_embed.weight.copy_(initial_tables(self.cfg, self._num_tables()))
        for p in (self.state_token, self.extra_state_tokens, self.mask_token):
            if p is not None:
                nn.init.normal_(p, std=0.02)
        for p in self.sensor_embed.values():
            nn.init.normal_(p, std=self.cfg.sensor_embed_std)

    def layout(self, channels: dict[str, Tensor], T: int, encoded: tuple[str, ...] = ()
               ) -> tuple[Tensor, Tensor, Tensor]:
        """Token layout of one sample, sensors in config order, time-major within a sensor:
        the scalar sensors' tokens (``channels``), then the ``encoded`` sensors' (k per step).

        Returns pos (N, d) fixed embedding, sensor_id (N,) into the present sensors (scalar
        ones first), step (N,).
        """
        return self._cached_layout(channels, T, encoded)[:3]

    def _row_offsets(self, channels: dict[str, Tensor], T: int) -> Tensor:
        """(N_scalar,) first row of each scalar token's value table in ``bin_embed``."""
        return self._cached_layout(channels, T, ())[3]

    def _cached_layout(self, channels: dict[str, Tensor], T: int,
                       encoded: tuple[str, ...]) -> tuple[Tensor, ...]:
        key = (
            T,
            tuple((n, tuple(c.tolist())) for n, c in channels.items()),
            encoded,
            self.bin_embed.weight.device,
        )
        if key not in self._pos_cache:
            self._pos_cache[key] = self._build_layout(channels, T, encoded)
            if len(self._pos_cache) > 64:
                self._pos_cache.pop(next(iter(self._pos_cache)))
        return self._pos_cache[key]

    @torch.inference_mode(False)  # cached: must stay usable by training after an act()
    def _build_layout(self, channels: dict[str, Tensor], T: int, encoded: tuple[str, ...]
                      ) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
        with torch.no_grad():
            dev = self.bin_embed.weight.device
            pos, sid, step, offset = [], [], [], [torch.zeros(0, dtype=torch.long, device=dev)]
            chan, first = [], 0  # every input channel's number, counted over the sensors
            groups = [(name, ch.to(dev), True) for name, ch in channels.items()]
            groups += [(name, torch.arange(get(name).encoder_tokens, device=dev), False)
                       for name in encoded]  # token j of step t at "channel" j
            for s, (name, ch, scalar) in enumerate(groups):
                t = torch.arange(T, device=dev).repeat_interleave(len(ch))  # (T*c,) oldest first
                c = ch.repeat(T)  # (T*c,)
                age = (T - 1 - t) if self.cfg.attention != "step" else torch.zeros_like(t)  # step: ages at readout
                pos.append(sincos_2d(c.float(), age.float(), self.cfg.dim, self.cfg.pos_base))
                sid.append(torch.full_like(t, s))
                step.append(t)
                chan.append(first + torch.arange(len(ch), device=dev).repeat(T))
                first += len(ch)
                if scalar:
                    offset.append(self.table_of(name, c) * self.cfg.num_bins)  # (T*c,)
            return (torch.cat(pos), torch.cat(sid), torch.cat(step), torch.cat(offset),
                    token_keys(torch.cat(step), torch.cat(chan), T))

    def embed(self, inputs: MSTAInputs, mask_ratio: float,
              generator: torch.Generator | None = None, dummy_tokens: int | Tensor = 0
              ) -> tuple[Tensor, Tensor | None]:
        """Tokens after masking, D dummy tokens, then the readout tokens (<S> last):
        (B, K + D + R, d), and a key mask (B, 1, 1, K + D + R) or None."""
        return self.embed_steps(inputs, mask_ratio, generator, dummy_tokens)[:2]

    def embed_steps(self, inputs: MSTAInputs, mask_ratio: float,
                    generator: torch.Generator | None = None, dummy_tokens: int | Tensor = 0
                    ) -> tuple[Tensor, Tensor | None, Tensor | None, int]:
        """:meth:`embed`; with ``attention`` = ``step`` also the age (B, K + D) of each token
        before the readout tokens (``axial``: its key, ``token_keys``; None in ``full``), and
        T when those are the whole token layout of the T-step window in its order (nothing
        removed, no dummy; else 0)."""
        if self.cfg.tokens == "sensor":
            return sensor_embed_steps(self, inputs, mask_ratio, generator, dummy_tokens)
        return self._embed_scalar_steps(inputs, mask_ratio, generator, dummy_tokens)

    def _embed_scalar_steps(self, inputs: MSTAInputs, mask_ratio: float,
                            generator: torch.Generator | None, dummy_tokens: int | Tensor
                            ) -> tuple[Tensor, Tensor | None, Tensor | None, int]:
        """:meth:`embed_steps` with the paper's tokens, one per scalar reading."""
        missing = None
        if self.mask_token is not None:
            inputs, missing = complete_inputs(inputs, self.scalar_sensors)  # absent sensors/channels -> mask tokens
        names, encoded = list(inputs.bins), tuple(inputs.encoded)
        first = inputs.bins[names[0]] if names else inputs.encoded[encoded[0]]
        B, T = first.shape[:2]
        # each token as its bin row (B, N) long, or, with encoded sensors, its value (B, N, d)
        tokens = self.rows(inputs) if names else None
        if encoded:
            tokens = self._encode(inputs, tokens, B, T)
        N = tokens.shape[1]
        pos, sid, step = self.layout(inputs.channels, T, encoded)  # (N, d), (N,), (N,)
        sensor = torch.stack([self.sensor_embed[n] for n in (*names, *encoded)])  # (S, d)
        static = pos + sensor[sid]  # (N, d)
        pad = inputs.pad[:, step] if inputs.pad is not None else None  # (B, N) True = padded token
        if missing is not None:
            miss = torch.cat([missing[n].repeat(T) for n in names]  # encoded: never missing
                             + [torch.zeros(T * get(n).encoder_tokens, dtype=torch.bool,
                                            device=static.device) for n in encoded])
            miss = miss[None].expand(B, -1)  # (B, N)
            pad = miss if pad is None else pad | miss
        gone = absent_tokens(inputs, B, T)  # (B, N) True = absent for that sample, or None
        # no masking skips round(): a traced N is a tensor (TorchScript / ONNX export)
        n_drop = N - num_kept(N, mask_ratio) if mask_ratio > 0 else 0
        if self.mask_token is not None:  # absent tokens are replaced like missing ones
            pad = pad if gone is None else gone if pad is None else pad | gone
            x = self._replace_masked(tokens, static, pad, n_drop, generator)  # (B, N, d)
            key_pad, keep = encoded_keys(gone, inputs, T), None  # key_pad: None unless an encoded sensor is absent
        elif gone is not None and torch.jit.is_tracing() and not mask_ratio:
            x, key_pad = self._value(tokens) + static, gone if pad is None else gone | pad
            keep = None
        elif gone is not None:  # per sample: (B, K, d), K the most any sample keeps
            keep, key_pad = keep_per_sample(gone, pad, mask_ratio, generator)
            x = self._gather(tokens, static, keep)
        else:
            x, key_pad, keep = self._remove_masked(tokens, static, pad, n_drop, generator)  # (B, K, d)
        where, ages = self._ages(step, T, inputs.channels, encoded, keep, B)  # (N,), (B, K)
        D = dummy_tokens.shape[1] if isinstance(dummy_tokens, Tensor) else dummy_tokens
        if D:
            dummy, slot = draw_dummy_tokens(self, inputs, pos, sensor, B, dummy_tokens, generator)
            x = torch.cat([x, dummy], dim=1)  # (B, K + D, d)
            ages = None if ages is None else torch.cat([ages, where[slot]], dim=1)
        x = torch.cat([x, self.readout_tokens().expand(B, -1, -1)], dim=1)  # (B, K + D + R, d)
        whole = T if keep is None and not D and self.mask_token is None else 0
        attn_mask = None
        if key_pad is not None and key_pad.any():
            # (B, L) True = may be attended to; dummy and readout tokens are always visible
            always = D + self.cfg.state_tokens
            keep = torch.cat([~key_pad, key_pad.new_ones(B, always)], dim=1)
            attn_mask = keep[:, None, None, :]  # (B, 1, 1, K + D + R)
            if torch.jit.is_tracing():  # exported: 0 / -inf added to the scores (cheaper)
                attn_mask = additive_mask(attn_mask, x.dtype)
        return x, attn_mask, ages, whole

    def _ages(self, step: Tensor, T: int, channels: dict[str, Tensor], encoded: tuple[str, ...],
              keep: Tensor | None, B: int) -> tuple[Tensor | None, Tensor | None]:
        """What the attention reads of each token of the layout (N,) and of the kept ones
        (B, K): step attention its age, axial attention its key (``token_keys``); full
        attention nothing (None, None). ``step`` (N,) is each token's step, 0 the oldest."""
        if self.cfg.attention == "full":
            return None, None
        where = (T - 1 - step if self.cfg.attention == "step"
                 else self._cached_layout(channels, T, encoded)[4])
        age = where[None].expand(B, -1)  # (B, N)
        return where, age if keep is None else torch.gather(age, 1, keep)

    def _encode(self, inputs: MSTAInputs, rows: Tensor | None, B: int, T: int) -> Tensor:
        """Every token's value (B, N, d): the scalar tokens' table rows, then each encoded
        sensor's k tokens per step (time-major, the order of :meth:`layout`)."""
        d = self.cfg.dim
        values = [self.bin_embed(rows)] if rows is not None else []
        for name, z in inputs.encoded.items():  # z: (B, T, dim) clipped z-scores
            k = get(name).encoder_tokens
            values.append(self.encoders[name](z).reshape(B, T * k, d))
        return torch.cat(values, dim=1)

    def _value(self, tokens: Tensor, keep: Tensor | None = None) -> Tensor:
        """Token values (B, N or K, d) from bin rows (B, N) or values (B, N, d), optionally
        only the ``keep`` (B, K) ones (rows are gathered before the lookup: cheaper)."""
        if tokens.is_floating_point():
            if keep is None:
                return tokens
            return torch.gather(tokens, 1, keep[..., None].expand(-1, -1, tokens.shape[-1]))
        return self.bin_embed(tokens if keep is None else torch.gather(tokens, 1, keep))

    def readout_tokens(self) -> Tensor:
        """<S> (last) after the other readout tokens: (R, d)."""
        if self.extra_state_tokens is None:
            return self.state_token[None]
        return torch.cat([self.extra_state_tokens, self.state_token[None]])

    def rows(self, inputs: MSTAInputs) -> Tensor:
        """Each token's row in ``bin_embed`` (its table's offset + its bin): (B, N), sensors
        in config order, time-major within each sensor (the order of :meth:`layout`)."""
        names = list(inputs.bins)
        bins = torch.cat([inputs.bins[n].flatten(1) for n in names], dim=1)  # (B, N)
        if self.cfg.value_embedding == "shared":
            return bins
        T = inputs.bins[names[0]].shape[1]
        return bins + self._row_offsets(inputs.channels, T)[None, :].to(bins.device)  # (B, N)

    def _drop_scores(self, B: int, N: int, pad: Tensor | None,
                     generator: torch.Generator | None) -> Tensor:
        """Random keep scores (B, N) in [0, 1) (:func:`msta.policies.base.uniform`); padded tokens
        get -1 so they are dropped first."""
        scores = uniform(B, N, generator, self.bin_embed.weight.device)
        return scores.masked_fill(pad, -1.0) if pad is not None else scores

    def keep_draw(self, B: int, N: int, pad: Tensor | None, n_drop: int,
                  generator: torch.Generator | None) -> Tensor:
        """Test-time removal's draw: the indices (B, N - n_drop) of the tokens each sample
        keeps, padded tokens removed first."""
        scores = self._drop_scores(B, N, pad, generator)  # (B, N)
        return torch.topk(scores, N - n_drop, dim=1, sorted=False).indices

    def _remove_masked(self, tokens: Tensor, static: Tensor, pad: Tensor | None, n_drop: int,
                       generator: torch.Generator | None
                       ) -> tuple[Tensor, Tensor | None, Tensor | None]:
        """Kept tokens (B, K, d), their key padding (B, K) or None, and their indices (B, K)
        into the layout (None: all N kept)."""
        B, N = tokens.shape[:2]
        if pad is not None:  # padding every sample shares is removed even beyond round(αN)
            n_drop = max(n_drop, int(pad.sum(1).min()))
        if n_drop == 0:
            return self._value(tokens) + static, pad, None  # (B, N, d)
        keep = self.keep_draw(B, N, pad, n_drop, generator)  # (B, K)
        return self._gather(tokens, static, keep), (
            torch.gather(pad, 1, keep) if pad is not None else None), keep

    def _gather(self, tokens: Tensor, static: Tensor, keep: Tensor) -> Tensor:
        """The ``keep`` (B, K) tokens' values plus their position and sensor type: (B, K, d)."""
        # index_select, not static[keep]: advanced indexing's backward (an accumulating
        # index_put) sums rows in a thread-dependent order on CPU; index_select's does not
        return self._value(tokens, keep) + static.index_select(0, keep.reshape(-1)).view(
            *keep.shape, -1)  # (B, K, d)

    def _replace_masked(self, tokens: Tensor, static: Tensor, pad: Tensor | None, n_drop: int,
                        generator: torch.Generator | None) -> Tensor:
        B, N = tokens.shape[:2]
        masked = (pad.clone() if pad is not None  # (B, N)
                  else torch.zeros_like(tokens[..., 0] if tokens.is_floating_point() else tokens,
                                        dtype=torch.bool))
        if n_drop:
            scores = self._drop_scores(B, N, pad, generator)  # (B, N)
            drop = torch.topk(-scores, n_drop, dim=1).indices  # (B, n_drop)
            masked.scatter_(1, drop, True)
        value = torch.where(masked[..., None], self.mask_token, self._value(tokens))  # (B, N, d)
        return value + static  # (B, N, d): position and sensor type are kept for masked tokens

    def features(self, x: Tensor, attn_mask: Tensor | None, ages: Tensor | None,
                 whole: int) -> Tensor:
        """The readout features (B, R * d) the head reads, from :meth:`embed_steps`'s tokens,
        key mask, ages and whole-layout T."""
        if self.cfg.attention != "full":
            features = step_features if self.cfg.attention == "step" else axial_features
            return features(self, x, attn_mask, ages, whole)
        R, last = self.cfg.state_tokens, len(self.blocks) - 1
        for i, block in enumerate(self.blocks):
            # the head reads only the readout tokens: the last block computes only theirs
            x = block(x, attn_mask, R if i == last else None)  # (B, L, d); last: (B, R, d)
        return self.ln_f(x).flatten(1)  # <S> (+ R - 1)

    def forward(self, inputs: MSTAInputs, mask_ratio: float = 0.0,
                generator: torch.Generator | None = None, dummy_tokens: int | Tensor = 0,
                with_aux: bool = False) -> Tensor | tuple[Tensor, Tensor]:
        """(B, action_dim); with ``with_aux`` also the auxiliary target's prediction
        (B, its dim) from the same readout features."""
        features = self.features(*self.embed_steps(inputs, mask_ratio, generator, dummy_tokens))
        if with_aux:
            if self.aux_head is None:
                raise ValueError("this MSTA student has no aux_target")
            return self.head(features), self.aux_head(features)
        return self.head(features)  # (B, action_dim)


@register_policy("msta", kind="method")
class MSTAPolicy(StudentPolicy):
    """MSTA student: processor (statistics, bins) + transformer.

    Args:
        config: an :class:`MSTAConfig`.
        processor: an :class:`MSTAProcessor` built from the dataset statistics.
    """

    config_class = MSTAConfig
    processor_class = MSTAProcessor
    supports_dummy_tokens = True
    supports_absent = True

    def __init__(self, config: MSTAConfig, processor: MSTAProcessor) -> None:
        super().__init__(config, processor)
        self.model = MSTATransformer(config)

    def forward(self, batch: Batch, channels: Channels | None = None,
                mask_ratio: float | None = None, generator: torch.Generator | None = None,
                dummy_tokens: int | Tensor = 0, absent: Absent | None = None,
                with_aux: bool = False) -> Tensor | tuple[Tensor, Tensor]:
        """Raw batch -> model-space action (B, A); mask_ratio defaults to the config's in
        training mode and 0 in eval mode; ``dummy_tokens`` random tokens are appended to
        every sample (the stress test, see the module docstring; a (B, D, 4) tensor of
        uniforms fixes their draws); ``absent`` (sensor -> (B, dim) bool over the full
        channels) removes a sample's channels (:mod:`msta.policies.msta.removal`);
        ``with_aux``: also the ``aux_target`` prediction (raw units)."""
        mask_ratio = self.resolve_mask_ratio(mask_ratio)
        inputs = self.processor.discretize(self.as_tensors(batch), channels)
        if absent is not None:
            first = next(iter((*inputs.bins.values(), *inputs.encoded.values())))
            inputs.absent = self.absent_masks(absent, first.shape[0])
        return self.model(inputs, mask_ratio, generator, dummy_tokens, with_aux)

    @property
    def target_columns(self) -> tuple[str, ...]:
        """The action column, and the ``aux_target``'s column when there is one."""
        aux = self.config.aux_target
        return (*super().target_columns, *((get(aux).column,) if aux else ()))

    def loss(self, batch: Batch, channels: Channels | None = None,
             mask_ratio: float | None = None, generator: torch.Generator | None = None,
             dummy_tokens: int = 0, absent: Absent | None = None
             ) -> tuple[Tensor, dict[str, float]]:
        """:meth:`StudentPolicy.loss`; with ``aux_target`` the readout also predicts that
        signal and ``aux_weight`` times its MSE (``aux_mse``) is added to the returned loss
        (the ``loss`` metric stays the action's, comparable with other students)."""
        if not self.config.aux_target:
            return super().loss(batch, channels, mask_ratio, generator, dummy_tokens, absent)
        key, column = self.target_columns
        missing = [k for k in (key, column) if k not in batch]
        if missing:
            raise KeyError(f"batch has no {missing[0]!r} (aux_target="
                           f"{self.config.aux_target!r} reads it); keys: {sorted(batch)}")
        batch = self.as_tensors(batch)
        if dummy_tokens:
            self.check_dummy_tokens(dummy_tokens)
        inputs = {k: v for k, v in batch.items() if k != column}  # the target is no input
        pred, aux = self(inputs, channels, mask_ratio, generator, dummy_tokens, absent,
                         with_aux=True)
        action_loss, metrics = self.action_loss(pred, batch[key])
        aux_loss = F.mse_loss(aux, batch[column].to(aux.dtype))
        metrics["aux_mse"] = float(aux_loss.detach())
        return action_loss + self.config.aux_weight * aux_loss, metrics

    def with_inputs(self, sensors: Sequence[str], history: int,
                    stats: Mapping[str, Mapping[str, Any]] | None = None) -> Self:
        """:func:`msta.policies.msta.inputs_copy.with_inputs` of this policy."""
        return with_inputs(self, sensors, history, stats)
