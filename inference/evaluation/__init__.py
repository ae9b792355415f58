"""Evaluation of shipped or trained models: the paper's Tables 4 and 7 (``evaluate``) and training runs side by
side (``compare``). onnxruntime and the simulator; torch only to read training records."""
