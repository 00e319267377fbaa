"""Does the learner's bf16 mode learn like fp32? `python -m studies.precision_parity` compares a
method's bf16 seeds with its fp32 seeds' band (docs/results/bf16_parity.md).
"""
