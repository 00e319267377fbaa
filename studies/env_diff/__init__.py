"""What differs between the authors' Fetch*-v1 (mujoco-py, MuJoCo 2.1) and Fetch*-v4 (MuJoCo 3).

    python -m studies.env_diff            # push, pick, slide: ~5 min on one core

Models, initial states, dynamics under the same actions, reward and success, per task. Writes
docs/results/env_diff.{md,json} (`--out STEM`), keeping the report's hand-written conclusion."""
