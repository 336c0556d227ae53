"""ONNX export (fp32 and int8 QDQ) per docs/contracts.md#onnx-model, and the checks run on exported files."""

import logging

# Noise on every command, none of it actionable here: torchao logs each optional CUDA kernel
# library it cannot load, torch a deprecation for torchao's enum registration, and the ONNX
# exporter each torchvision op it skips because torchvision is not installed.
for _name in ("torchao", "torch.utils._pytree", "torch.onnx._internal.exporter._registration"):
    logging.getLogger(_name).setLevel(logging.ERROR)
