"""Torch-free CPU runtime: onnxruntime session, mask filters, moments grasps, geometry, robots.

Nothing under this package may import torch (tests/runtime/test_no_torch.py enforces it).
"""
