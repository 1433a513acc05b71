"""Training the paper's RMA teacher: rsl_rl's PPO on msta's simulator, warm-started by
DAgger from the gait controller (``msta-train-teacher``)."""
