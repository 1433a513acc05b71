"""int8 ONNX graphs for deployment: ONNX Runtime's dynamic quantization.

The weights of every matrix product (``MatMul``, the linear layers) are stored as int8 with
one scale per weight matrix; at each call ONNX Runtime quantizes the activations entering
them to uint8 (range measured on the call) and multiplies in integers (VNNI / AMX where the
CPU has them). Attention's score and value products, normalization and softmax stay fp32.
Actions move by a few hundredths of a model-space unit (docs/deploy.md), so an int8 student
is accepted on its closed-loop figures, not on a parity tolerance.

This module must not import torch (it serves :mod:`msta.policies.onnx_runtime` too).
"""

from __future__ import annotations

import logging
import tempfile
from pathlib import Path

__all__ = ["int8_graph", "write_int8"]


def write_int8(source: str | Path, target: str | Path) -> Path:
    """Quantize the ONNX file ``source`` into ``target`` (int8 weights of the matrix
    products, activations quantized per call); returns ``target``."""
    # lazy: onnxruntime's quantization tools (and onnx) load only where a graph is quantized
    from onnxruntime.quantization import QuantType, quantize_dynamic

    previous = logging.root.manager.disable
    logging.disable(logging.WARNING)  # its advice to pre-process (shape inference) for static quantization
    try:
        quantize_dynamic(Path(source), Path(target), op_types_to_quantize=["MatMul", "Gemm"],
                         weight_type=QuantType.QInt8)
    finally:
        logging.disable(previous)
    return Path(target)


def int8_graph(graph: bytes) -> bytes:
    """An ONNX graph's bytes -> the bytes of its int8 version (:func:`write_int8`)."""
    with tempfile.TemporaryDirectory() as tmp:
        src, dst = Path(tmp) / "fp32.onnx", Path(tmp) / "int8.onnx"
        src.write_bytes(graph)
        return write_int8(src, dst).read_bytes()
