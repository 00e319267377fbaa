"""`hercs eval`: a trained policy's success rate and its video."""
