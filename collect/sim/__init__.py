"""Batched MuJoCo simulation of an A1-class quadruped on legged_gym-style terrain (the GL
backend default is set by :mod:`msta.collect`, which Python imports first)."""

from gymnasium.envs.registration import register, registry

# Gymnasium: importing this package registers "msta/A1-v0" (see gym_env.py), the way
# Gymnasium's plugin packages do. The entry points are strings, so MuJoCo and gym_env load
# only when an env is made.
if "msta/A1-v0" not in registry:
    register(id="msta/A1-v0", entry_point="msta.collect.sim.gym_env:MstaEnv",
             vector_entry_point="msta.collect.sim.gym_env:MstaVectorEnv")
