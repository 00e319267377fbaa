"""What differs between the authors' Fetch*-v1 (mujoco-py, MuJoCo 2.1) and Fetch*-v4 (MuJoCo 3).

    python -m studies.env_diff            # push, pick, slide: ~5 min on one core
    python -m studies.env_diff --quick    # CI: push only, a few resets and episodes (< 20 s)

Both versions load the same XML files (gymnasium-robotics' assets) and run the same Python task
code; what can differ is the simulator that compiles and steps them. Per task, with one v1 and
one v4 env made by `hercs.rl.envs.make_env`:

1. **Models.** The physics options (timestep, substeps, integrator, solver, cone, …, and the
   options or flags one version has and the other lacks) and, for the object, the table, the
   floor, the gripper's fingers and link, the object's free joint, the fingers' joints and
   actuators, and the mocap weld: every parameter that decides contact and motion, side by side.
   Then every numeric mjModel field the two bindings share, compared element by element, so that
   nothing outside the curated list differs unseen.
2. **Initial states.** `--resets` resets with seeds 0..N-1: the object's xy, the goal, the
   gripper, the share of goals within 5 cm of the object's start (an episode the agent succeeds
   in by leaving the object alone), the object's and the fingers' penetration into the table,
   the contacts at reset; and, over a few episodes of zero actions, how far things drift.
3. **Dynamics under the same actions.** (a) free-space gripper tracking; (b) a controlled push:
   the object placed in front of the fingers, pushed at 0.25/0.5/1.0 of full speed, then the
   gripper withdrawn (object travel per unit of gripper travel, slide after contact ends, yaw);
   (c) a free slide: the object given a velocity on the table, stepped substep by substep
   (stopping distance against Coulomb's v²/2μg); (d) a scripted closed-loop push towards the
   goal and (e) uniform random actions (one seeded sequence for both), each from matched
   initial states (v4 set to v1's full simulator state after the same reset) and from each
   env's own reset: success, object motion, contacts, and the per-step divergence of gripper
   and object between the two simulators.
4. **Reward and success.** `compute_reward` and `is_success` of both envs, and
   `hercs.rl.task_registry.fetch_reward`, on the same random goal pairs and on every step of
   (d)/(e).

`--variant` repeats the dynamics of 3 for v4 with a model override (e.g. `legacy-ccd`: MuJoCo
3's native and multi-point CCD disabled), to test whether a v4 setting closes a gap.

Writes `docs/results/env_diff.{md,json}` (`--out STEM`).
"""
