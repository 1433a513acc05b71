"""An MSTA policy with per-step attention (``--policy.attention=step``) on a robot, one control
step at a time (:mod:`msta.policies.msta.step_attention` says why a step's tokens can be
reused).

Each :meth:`StepStream.step` runs two parts: the **encoder** reads the newest step's
readings (processor, tokens, the per-step blocks) and returns that step's keys and values
for every readout block (before their age); the **readout** takes the last T steps' cached
keys and values, adds each step's age and runs the readout blocks and the head. The cache
is a ring of T slots, oldest first; slots before the episode's first step are hidden from
attention, so the first steps act on the shorter window exactly as the policy does on a
padded one. ``runtime`` picks what runs the two parts: ``eager`` PyTorch, ``torchscript``
(traced once at construction and frozen), ``onnxruntime`` (exported once to ONNX, run on
ONNX Runtime's CPU provider) or ``onnxruntime-int8`` (the same graphs with the weights of
their matrix products in int8 and activations quantized per call: ONNX Runtime's dynamic
quantization, a small loss of precision); the last three remove most of the per-call
overhead at batch 1.
"""

from __future__ import annotations

import io
import warnings
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import torch
from torch import Tensor, nn

from msta.data.sensors import get
from msta.policies.export_files import ONNX_OPSET
from msta.policies.msta.step_attention import age_code, readout_block, token_kv
from msta.policies.quantize import int8_graph

__all__ = ["RUNTIMES", "StepStream"]

#: What may run a stream's two parts.
RUNTIMES = ("eager", "torchscript", "onnxruntime", "onnxruntime-int8")


class _Encoder(nn.Module):
    """One step's readings (each (B, dim), ``sensors`` order) -> its keys and values per
    readout block (B, readout_layers, n, 2d)."""

    def __init__(self, policy: Any, sensors: Sequence[str]) -> None:
        super().__init__()
        self.policy, self.sensors = policy, tuple(sensors)
        self.n_step = policy.config.num_layers - policy.config.readout_layers

    def forward(self, *readings: Tensor) -> Tensor:
        model = self.policy.model
        batch = {n: r[:, None] for n, r in zip(self.sensors, readings, strict=True)}  # (B, 1, dim)
        inputs = self.policy.processor.discretize(self.policy.as_tensors(batch))
        tokens = model.embed_steps(inputs, 0.0)[0][:, :-model.cfg.state_tokens]  # (B, n, d)
        for block in model.blocks[:self.n_step]:
            tokens = block(tokens, None)
        return torch.stack([token_kv(b, tokens) for b in model.blocks[self.n_step:]], dim=1)


class _Readout(nn.Module):
    """Cached keys and values (B, readout_layers, T·n, 2d), the slots' age offsets
    (readout_layers, T·n, 2d) and visibility (B, T·n) -> the model-space action (B, A)."""

    def __init__(self, policy: Any) -> None:
        super().__init__()
        self.policy = policy
        self.n_step = policy.config.num_layers - policy.config.readout_layers

    def forward(self, kv: Tensor, age: Tensor, visible: Tensor) -> Tensor:
        model = self.policy.model
        readout = model.readout_tokens()[None].expand(kv.shape[0], -1, -1)  # (B, R, d)
        for i, block in enumerate(model.blocks[self.n_step:]):
            readout = readout_block(block, kv[:, i] + age[i], readout, visible)
        return model.head(model.ln_f(readout).flatten(1))


class StepStream:
    """An MSTA ``step`` policy acting one control step at a time: each :meth:`step` encodes
    the newest step only and reuses the cached keys and values of the last ``history - 1``
    steps. Its action equals the policy's model output on the window of those steps (float
    rounding aside).

    Args:
        policy: an :class:`~msta.policies.msta.modeling_msta.MSTAPolicy` whose config has
            ``attention`` = ``step`` (put in eval mode).
        history: steps in the window T (default: the policy's training window).
        sensors: the sensors read, in the order :meth:`step` is given them (default: every
            input of the policy).
        batch: robots stepped at once (the readings' first dimension).
        runtime: one of :data:`RUNTIMES` for the encoder and the readout (ONNX Runtime
            uses as many threads as torch).
    """

    def __init__(self, policy: Any, history: int | None = None,
                 sensors: Sequence[str] | None = None, batch: int = 1,
                 runtime: str = "eager") -> None:
        cfg = policy.config
        if cfg.attention != "step":
            raise ValueError(f"StepStream needs an MSTA policy with attention='step', this one "
                             f"has {cfg.attention!r}")
        if runtime not in RUNTIMES:
            raise ValueError(f"runtime must be one of {RUNTIMES}, got {runtime!r}")
        self.policy = policy.eval()
        self.history = history or cfg.history
        self.sensors = tuple(sensors or cfg.input_sensors)
        self.encoder: Any = _Encoder(self.policy, self.sensors).eval()
        self.readout: Any = _Readout(self.policy).eval()
        self.device = dev = next(policy.parameters()).device
        one = tuple(torch.zeros(batch, get(n).dim, device=dev) for n in self.sensors)
        with torch.inference_mode():
            kv = self.encoder(*one)  # (B, readout_layers, n, 2d)
            self.tokens_per_step = kv.shape[2]
            ages = torch.arange(self.history - 1, -1, -1, device=dev)  # oldest slot first
            self.age = torch.stack([proj(age_code(policy.model, ages)) for proj in
                                    policy.model.age_proj])  # (layers, T, 2d)
            self.age = self.age.repeat_interleave(self.tokens_per_step, dim=1)  # (layers, T·n, 2d)
        self._empty = (kv.new_zeros(batch, kv.shape[1], self.history * self.tokens_per_step,
                                    kv.shape[3]),
                       torch.zeros(batch, self.history * self.tokens_per_step, dtype=torch.bool,
                                   device=dev))
        if runtime != "eager":
            compiled = _frozen if runtime == "torchscript" else _onnx
            int8 = runtime == "onnxruntime-int8"
            with torch.no_grad():
                self.encoder = compiled(self.encoder, one, self.sensors, int8)
                self.readout = compiled(self.readout, (self._empty[0], self.age, ~self._empty[1]),
                                        ("kv", "age", "visible"), int8)
        self.reset()

    def reset(self) -> None:
        """Forget the cached steps (a new episode)."""
        self._kv, self._visible = (t.clone() for t in self._empty)

    @torch.inference_mode()
    def step(self, readings: Mapping[str, Any]) -> Tensor:
        """One control step: ``readings`` maps each of :attr:`sensors` to this step's values
        (B, dim); returns the model-space action (B, action_dim) on the window ending here."""
        new = self.encoder(*(torch.as_tensor(readings[n], dtype=torch.float32, device=self.device)
                             for n in self.sensors))  # (B, layers, n, 2d)
        n = self.tokens_per_step
        self._kv = torch.cat([self._kv[:, :, n:], new], dim=2)
        self._visible = torch.cat([self._visible[:, n:], self._visible.new_ones(
            self._visible.shape[0], n)], dim=1)
        return self.readout(self._kv, self.age, self._visible)


def _frozen(module: nn.Module, example: tuple[Tensor, ...], names: Sequence[str],
            int8: bool = False) -> Any:
    """``module`` traced on ``example`` and frozen for inference (TorchScript); ``names``
    (of the inputs) and ``int8`` (ONNX Runtime's) are unused here."""
    with warnings.catch_warnings():
        # TracerWarnings name the eager path's Python checks, which the graph leaves out
        warnings.simplefilter("ignore", torch.jit.TracerWarning)
        traced = torch.jit.trace(module, example, check_trace=False)
    return torch.jit.optimize_for_inference(torch.jit.freeze(traced))


def _onnx(module: nn.Module, example: tuple[Tensor, ...], names: Sequence[str],
          int8: bool = False) -> Callable[..., Tensor]:
    """``module`` exported to ONNX (inputs ``names``, traced on ``example``), its weights
    quantized to int8 when ``int8`` (:func:`msta.policies.quantize.int8_graph`), and a
    function running it on ONNX Runtime's CPU provider: tensors in, a tensor out."""
    import onnxruntime as ort  # lazy: onnxruntime loads only where an ONNX graph runs

    buffer = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # TracerWarnings: the eager path's Python checks
        torch.onnx.export(module, example, buffer, dynamo=False, input_names=list(names),
                          output_names=["out"], opset_version=ONNX_OPSET)
    graph = int8_graph(buffer.getvalue()) if int8 else buffer.getvalue()
    options = ort.SessionOptions()
    options.intra_op_num_threads = options.inter_op_num_threads = torch.get_num_threads()
    session = ort.InferenceSession(graph, options, providers=["CPUExecutionProvider"])

    def run(*inputs: Tensor) -> Tensor:
        feed = {n: x.cpu().numpy() for n, x in zip(names, inputs, strict=True)}
        return torch.from_numpy(session.run(None, feed)[0]).to(inputs[0].device)
    return run
