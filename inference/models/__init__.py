"""The shipped models: ``shipped/`` holds the ONNX files, their card and trust.json (no code; the networks'
code is ``inference.networks``)."""
