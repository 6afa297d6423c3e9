"""Deployment: a trained model outside Python and PyTorch (ONNX export, a Drake-native system)."""
