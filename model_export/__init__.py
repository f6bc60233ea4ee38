"""Training and ONNX export of the neural ShDF network (needs the ``train`` extra: torch)."""
