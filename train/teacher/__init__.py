"""Training the paper's RMA teacher: rsl_rl's PPO on msta's simulator, warm-started by
imitation of the gait controller (``msta-train-teacher``)."""
