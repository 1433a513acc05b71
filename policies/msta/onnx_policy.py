"""An MSTA policy whose network runs as one ONNX Runtime graph, fp32 or int8: a deployment
graph driven in closed loop by msta's own rollouts and evaluation.

:class:`OnnxMSTA` acts as the policy it wraps does (:meth:`~msta.policies.base.StudentPolicy.act`:
raw windows in, joint targets out, the same test-time removal) with the network's forward
in ONNX Runtime. The graph takes the window's every token and a (B, N) ``visible`` mask:
the tokens the policy would remove (its own random draw from the same generator, and the
padding before an episode's first step) are hidden from attention instead of dropped, which
gives the same action up to float rounding (the readout only reads what it can attend to).
Sensor tokens (``tokens='sensor'``) take the kept readings (B, T, M) in place of
``visible``: the policy's own draw over single readings, a token with none left hidden.
With ``int8`` the graph's matrix products run with int8 weights
(:func:`msta.policies.quantize.int8_graph`), so an evaluation of it measures what
quantization costs in closed loop.
"""

from __future__ import annotations

import io
import warnings
from collections.abc import Sequence
from typing import Any

import torch
from torch import Tensor, nn

from msta.data.sensors import get
from msta.policies.export_files import ONNX_OPSET
from msta.policies.msta.removal import additive_mask, visible_tokens
from msta.policies.msta.sensor_tokens import draw_readings, sensor_embed_steps
from msta.policies.quantize import int8_graph

__all__ = ["OnnxMSTA"]


class _VisibleGraph(nn.Module):
    """Raw windows (each (B, T, dim), ``sensors`` order) and ``visible`` (B, N) bool ->
    the model-space action (B, A), hidden tokens out of every attention."""

    def __init__(self, policy: Any, sensors: Sequence[str]) -> None:
        super().__init__()
        self.policy, self.sensors = policy, tuple(sensors)

    def forward(self, *inputs: Tensor) -> Tensor:
        *windows, visible = inputs
        model = self.policy.model
        batch = dict(zip(self.sensors, windows, strict=True))
        x, _, ages, _ = model.embed_steps(self.policy.processor.discretize(
            self.policy.as_tensors(batch)), 0.0)  # every token, readout tokens last
        keys = torch.cat([visible, visible.new_ones(visible.shape[0], model.cfg.state_tokens)], 1)
        mask = additive_mask(keys[:, None, None, :], x.dtype)  # (B, 1, 1, N + R)
        return model.head(model.features(x, mask, ages, 0))


class _KeptGraph(_VisibleGraph):
    """Sensor tokens: raw windows and ``kept`` (B, T, M) bool, the readings kept (every
    channel of every sensor, ``sensors`` order) -> the model-space action (B, A); a token
    with no reading kept is out of every attention."""

    def forward(self, *inputs: Tensor) -> Tensor:
        *windows, kept = inputs
        model = self.policy.model
        tensors = self.policy.processor.discretize(
            self.policy.as_tensors(dict(zip(self.sensors, windows, strict=True))))
        return model.head(model.features(*sensor_embed_steps(model, tensors, 0.0, None, 0,
                                                             kept=kept)))


class OnnxMSTA:
    """An MSTA policy (eval mode, CPU) with its network as an ONNX Runtime graph.

    Args:
        policy: an :class:`~msta.policies.msta.modeling_msta.MSTAPolicy` without
            ``learnable_mask`` (scalar or sensor tokens).
        history: the window T the graph is built for (default: the policy's).
        int8: quantize the graph's matrix-product weights to int8.
        num_threads: ONNX Runtime's intra-op threads (default: torch's).
    """

    def __init__(self, policy: Any, history: int | None = None, int8: bool = False,
                 num_threads: int | None = None) -> None:
        import onnxruntime as ort  # lazy: onnxruntime loads only where an ONNX graph runs

        if policy.model.mask_token is not None:
            raise ValueError("OnnxMSTA needs an MSTA policy that removes its tokens "
                             "(learnable_mask=false)")
        self.policy = policy.cpu().float().eval()
        self.config = policy.config
        self.int8 = int8
        self.history = int(history or policy.config.history)
        self.sensors = tuple(policy.required_sensors)
        #: sensor tokens take the kept readings (B, T, M), scalar ones the visible tokens (B, N)
        self.by_reading = policy.config.tokens == "sensor"
        graph = (_KeptGraph if self.by_reading else _VisibleGraph)(self.policy, self.sensors)
        example = tuple(torch.zeros(1, self.history, get(n).dim) for n in self.sensors)
        if self.by_reading:
            mask = torch.ones(1, self.history, sum(get(n).dim for n in self.sensors))
        else:
            mask = torch.ones(1, self.policy.model.layout(self.policy.processor.discretize(
                self.policy.as_tensors(dict(zip(self.sensors, example, strict=True)))
            ).channels, self.history)[2].shape[0])
        example += (mask.bool(),)
        names = [*self.sensors, "kept" if self.by_reading else "visible"]
        buffer = io.BytesIO()
        with warnings.catch_warnings(), torch.no_grad():
            warnings.simplefilter("ignore")  # TracerWarnings: the eager path's Python checks
            torch.onnx.export(graph, example, buffer, dynamo=False, input_names=names,
                              output_names=["action"], opset_version=ONNX_OPSET,
                              dynamic_axes={n: {0: "batch"} for n in [*names, "action"]})
        options = ort.SessionOptions()
        options.intra_op_num_threads = int(num_threads or torch.get_num_threads())
        options.inter_op_num_threads = 1
        data = int8_graph(buffer.getvalue()) if int8 else buffer.getvalue()
        self.session = ort.InferenceSession(data, options, providers=["CPUExecutionProvider"])
        self._names = names

    @property
    def required_sensors(self) -> tuple[str, ...]:
        """The wrapped policy's input sensors (every one is required: the graph's inputs)."""
        return self.sensors

    @property
    def device(self) -> torch.device:
        """Where the inputs go: the CPU (ONNX Runtime's CPU provider)."""
        return torch.device("cpu")

    def check_dummy_tokens(self, n: int) -> None:
        """Dummy tokens are not in the graph."""
        raise NotImplementedError("OnnxMSTA takes no dummy tokens")

    def act(self, batch: dict[str, Any], channels: Any = None, mask_ratio: float = 0.0,
            generator: torch.Generator | None = None, dummy_tokens: int = 0,
            absent: Any = None) -> Tensor:
        """Joint targets (B, 12) in raw units, as ``policy.act`` (every input sensor over
        the graph's T steps, optional ``"pad"``, test-time ``mask_ratio`` drawn from
        ``generator``); ``channels``, ``dummy_tokens`` and ``absent`` are not in the graph."""
        if channels or dummy_tokens or absent is not None:
            raise NotImplementedError("OnnxMSTA acts on every channel of every input sensor "
                                      "(no channels / dummy_tokens / absent)")
        policy = self.policy
        with torch.inference_mode():
            tensors = policy.as_tensors(batch)
            T = tensors[self.sensors[0]].shape[1]
            if T != self.history:
                raise ValueError(f"OnnxMSTA's graph takes windows of {self.history} steps, "
                                 f"got {T}")
            inputs = policy.processor.discretize(tensors)
            feed = {n: tensors[n].float().numpy() for n in self.sensors}
            if self.by_reading:  # (B, T, M)
                feed["kept"] = draw_readings(policy.model, inputs, mask_ratio, generator).numpy()
            else:  # (B, N)
                feed["visible"] = visible_tokens(policy.model, inputs, mask_ratio,
                                                 generator).numpy()
            action = torch.from_numpy(self.session.run(None, feed)[0])  # (B, A) model space
            return policy.processor.unnormalize_action(action)
