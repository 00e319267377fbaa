"""What each sampler feeds the learner: the mix of episodes HER and HER-CS draw from one run's
buffer (`python -m studies.sampler_mix RUN_DIR`).
"""
