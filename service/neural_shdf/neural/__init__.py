"""The neural ShDF's input graph and its onnxruntime inference (no torch here)."""
