"""Batched MuJoCo simulation of a quadruped described by a robot description (the A1 by
default) on legged_gym-style terrain (the GL backend default is set by :mod:`msta.collect`,
which Python imports first)."""

from gymnasium.envs.registration import register, registry

# Gymnasium: importing this package registers "msta/A1-v0" and "msta/Go1-v0" (see
# gym_env.py), the way Gymnasium's plugin packages do. The entry points are strings, so MuJoCo
# and gym_env load only when an env is made. msta/A1-v0 simulates EnvConfig.robot (the A1 by
# default); msta/Go1-v0 passes robot="go1".
if "msta/A1-v0" not in registry:
    register(id="msta/A1-v0", entry_point="msta.collect.sim.gym_env:MstaEnv",
             vector_entry_point="msta.collect.sim.gym_env:MstaVectorEnv")
if "msta/Go1-v0" not in registry:
    register(id="msta/Go1-v0", entry_point="msta.collect.sim.gym_env:MstaEnv",
             vector_entry_point="msta.collect.sim.gym_env:MstaVectorEnv",
             kwargs={"robot": "go1"})
