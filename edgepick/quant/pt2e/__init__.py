"""The torch passes (torchao's pt2e flow): a model is exported with torch.export, annotated by
edgepick's quantizer, calibrated or trained with fake-quant, converted and written as a QDQ ONNX
file by `edgepick.export`. The public verbs are named in `edgepick.quant`."""
