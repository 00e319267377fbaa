"""What differs between the authors' Fetch*-v1 (mujoco-py, MuJoCo 2.1) and Fetch*-v4 (MuJoCo 3).

    python -m studies.env_diff            # push, pick, slide: ~5 min on one core
    python -m studies.env_diff --quick    # CI: push only, a few resets and episodes (< 20 s)
    python -m studies.env_diff --variant legacy-ccd  # v4's dynamics again with a model override

Both versions load the same XML files and run the same task code, so what can differ is the
simulator that compiles and steps them. Per task, with one env of each from
`hercs.rl.envs.make_env`: (1) the models' physics options and contact parameters, then every
numeric mjModel field both bindings share; (2) `--resets` initial states; (3) dynamics under
the same actions, from matched states (v4 set to v1's state) and from each env's own reset;
(4) `compute_reward` and `is_success` against `hercs.rl.task_registry.fetch_reward`. Writes
docs/results/env_diff.{md,json} (`--out STEM`), whose sections 1–4 give each measurement; the
report keeps its hand-written conclusion (studies/study_output.py).
"""
