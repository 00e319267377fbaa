"""The product's performance benchmarks: throughput, sampling, inserts, the learner on CPU and
GPU, memory, log size, actors' env steps and whole runs' speed (`python -m bench.perf.<name>`).
Each pairs a figure of the system with a reference timed in the same run, since the machines
are shared and noisy; docs/PERFORMANCE.md collects their results.
"""
