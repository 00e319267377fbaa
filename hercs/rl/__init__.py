"""The learning problem, with no transport and no run directory: tasks and their specs, goal
environments, the networks and policy of DDPG, the observation normaliser, the cluster model of
HER-CS, the sampling methods and their episode samplers, and seeding."""
