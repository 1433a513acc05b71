"""msta-export's file names, format tags and defaults, and its parity error: what the export
(:mod:`msta.policies.export`) and its command line (:mod:`msta.policies.export_cli`) share."""

from __future__ import annotations

#: spec.json's format tag.
FORMAT = "msta-export/1"
#: The files an export writes.
SPEC_NAME = "spec.json"
TORCHSCRIPT_NAME = "student.pt"
ONNX_NAME = "student.onnx"
#: Largest |exported - eager| action difference an fp32 export may show.
DEFAULT_TOLERANCE = 1e-5
#: The ONNX opset the graph is written in.
ONNX_OPSET = 17
#: The formats ``--formats`` may name.
FORMATS = ("torchscript", "onnx")


class ExportParityError(RuntimeError):
    """An exported model's actions differ from the eager model's by more than the tolerance."""
