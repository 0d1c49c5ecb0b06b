"""Inference on lowered arrays: the E-step (NumPy reference and compiled twin) and the sufficient
statistics the M-steps consume. Nothing here knows which model components produced the arrays."""
