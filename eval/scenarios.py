"""The paper's test-time experiments as a registry of scenarios, and the suites that run them.

A *scenario* turns a student (its input sensors) and a suite's values into *conditions*:
one :class:`~msta.policies.input_spec.InputSpec` each (what the student sees at test time) plus the
label and x-axis value used in tables and plots. The teacher is the reference: no input
change applies to it.

Scenarios (registry :data:`SCENARIOS`):

1. ``token_removal``: random token removal at test time, 0 / 25 / 50 % (Table I).
2. ``sensor_removal``: one sensor removed entirely, for each sensor of the student.
3. ``dead_joints``: q and q̇ of k = 0..6 random joints removed (fixed seeds; the k-joint
   set is a prefix of one seeded permutation, so k + 1 adds a joint to the k set).
4. ``history``: the window length (``InputSpec.history``, labelled T = n as in the paper)
   without masking (T = 20 is longer than trained).
5. ``mask_matrix``: the token-removal conditions of checkpoints trained with different
   stage-1 x stage-2 mask ratios, shown as heatmaps (needs ``--matrix`` or ratios recorded
   in the checkpoints).
6. ``dummy_tokens``: N random "dummy" tokens appended to every sample of a token student
   (MSTA), 0 / 256 (quick) or 0 / 64 / 256 (paper); other students are not applicable.
7. ``sensor_faults``: a sensor that lies (``msta.collect.faults``: stuck, bias, drift, noise,
   spikes, dropout, scale) from a random onset on, each fault run three ways: the student
   unguarded, with the oracle removing exactly the faulty channels, and with the guard saved
   with the checkpoint (when it has one); plus the fault-free student. Not part of a
   suite's default scenarios (``--scenarios=sensor_faults``); the sweep is
   :data:`DEFAULT_FAULTS` unless msta-eval's ``--faults`` names others (docs/faults.md).

A *suite* (registry :data:`SUITES`) fixes trials, terrains, levels, episode length and the
values each scenario sweeps. :class:`TrialConfig` picks a suite and overrides its budget;
msta-eval's and msta-correct's ``--eval.*`` options are this one dataclass, so both run the
same trials for the same options.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from msta.collect.faults import FaultSpec
from msta.collect.sim.env_config import check_sizes, load_sim_robot
from msta.collect.sim.terrain import TERRAIN_TYPES, TerrainConfig
from msta.data.checks import check_at_least
from msta.data.robot import LEGACY_ROBOT, NUM_JOINTS
from msta.eval.metrics import TrialLayout
from msta.policies.input_spec import InputSpec

#: The paper's five terrain types (legged_gym curriculum); "flat" may be added by the user.
PAPER_TERRAINS: tuple[str, ...] = (
    "smooth_slope", "rough_slope", "stairs_up", "stairs_down", "discrete")


@dataclass(frozen=True)
class Condition:
    """One test-time setting of one scenario.

    Args:
        scenario: registry name of the scenario.
        label: short human label, e.g. ``"mask 25%"``.
        value: x-axis value in plots (ratio, sensor name, k, T).
        spec: what the student sees.
        fault: a sensor fault on the student's observation (sensor_faults), or None.
        removal: how faulty channels are removed (sensor_faults): "unguarded" (not at
            all), "oracle" (exactly the fault's, where active) or "guard" (what the
            checkpoint's guard flags); "" for the other scenarios.
    """

    scenario: str
    label: str
    value: float | int | str
    spec: InputSpec
    fault: FaultSpec | None = None
    removal: str = ""

    @property
    def key(self) -> str:
        return f"{self.scenario}/{self.label}"


@dataclass(frozen=True)
class ScenarioContext:
    """What a scenario needs to build its conditions for one student.

    Args:
        sensors: the student's input sensors (registry names).
        values: the suite's sweep values for this scenario.
        seed: seeds random choices (dead joints, token removal).
    """

    sensors: tuple[str, ...]
    values: tuple
    seed: int


@dataclass(frozen=True)
class Scenario:
    """A registered experiment.

    Args:
        name: registry key (``--scenarios`` accepts it).
        title: plot / table title.
        axis: x-axis label.
        build: context -> conditions (first one is the scenario's reference setting).
        plot: whether report.py draws a figure for it.
    """

    name: str
    title: str
    axis: str
    build: Callable[[ScenarioContext], list[Condition]]
    plot: bool = True


SCENARIOS: dict[str, Scenario] = {}


def register_scenario(scenario: Scenario) -> Scenario:
    """Add a scenario to :data:`SCENARIOS` (names are unique)."""
    if scenario.name in SCENARIOS:
        raise ValueError(f"scenario {scenario.name!r} registered twice")
    SCENARIOS[scenario.name] = scenario
    return scenario


def get_scenario(name: str) -> Scenario:
    """Registered scenario ``name``; the error lists the known names."""
    try:
        return SCENARIOS[name]
    except KeyError:
        raise KeyError(f"unknown scenario {name!r}; known scenarios: {sorted(SCENARIOS)}") \
            from None


def dead_joint_set(k: int, seed: int) -> tuple[int, ...]:
    """The k dead joints for ``seed``: the first k of one seeded permutation of 0..11 (sorted).

    Args:
        k: number of dead joint encoders (0..NUM_JOINTS).
        seed: fixes the permutation.
    """
    if not 0 <= k <= NUM_JOINTS:
        raise ValueError(f"dead joint count k={k} must be in [0, {NUM_JOINTS}]")
    perm = np.random.default_rng([seed, 0xDEAD]).permutation(NUM_JOINTS)
    return tuple(sorted(int(j) for j in perm[:k]))


def _token_removal(ctx: ScenarioContext) -> list[Condition]:
    return [Condition("token_removal", f"mask {round(100 * r)}%", float(r),
                      InputSpec(mask_ratio=float(r), seed=ctx.seed)) for r in ctx.values]


def _sensor_removal(ctx: ScenarioContext) -> list[Condition]:
    out = [Condition("sensor_removal", "none", "none", InputSpec(seed=ctx.seed))]
    return out + [Condition("sensor_removal", f"-{s}", s,
                            InputSpec(drop_sensors=(s,), seed=ctx.seed))
                  for s in (ctx.values or ctx.sensors)]


def _dead_joints(ctx: ScenarioContext) -> list[Condition]:
    return [Condition("dead_joints", f"k={k}", int(k),
                      InputSpec(dead_joints=dead_joint_set(int(k), ctx.seed), seed=ctx.seed))
            for k in ctx.values]


def _dummy_tokens(ctx: ScenarioContext) -> list[Condition]:
    return [Condition("dummy_tokens", f"dummy {int(n)}", int(n),
                      InputSpec(dummy_tokens=int(n), seed=ctx.seed)) for n in ctx.values]


def _history(ctx: ScenarioContext) -> list[Condition]:
    return [Condition("history", f"T={t}", int(t), InputSpec(history=int(t), seed=ctx.seed))
            for t in ctx.values]


#: The joint whose encoder (or q channel) the default fault sweep breaks: FL calf (the knee).
FAULT_JOINT = 2
#: sensor_faults' default sweep (one-string form, msta.collect.faults): every type at the
#: severity the issue's minimums name, on one joint encoder, one channel and a whole sensor.
DEFAULT_FAULTS: tuple[str, ...] = tuple(
    f"{kind}:{target}" for target in (f"encoder:{FAULT_JOINT}", f"joint_pos:{FAULT_JOINT}",
                                      "ang_vel")
    for kind in ("stuck:0", "bias:3", "noise:3", "spikes:5", "dropout:0.2", "drift:0.5",
                 "scale:1.5"))
#: How sensor_faults removes faulty channels, in table order.
REMOVALS: tuple[str, ...] = ("unguarded", "oracle", "guard")


def _sensor_faults(ctx: ScenarioContext) -> list[Condition]:
    """The fault-free student (unguarded and guarded), then every fault the student reads
    (values: one-string faults) x :data:`REMOVALS`; the evaluation drops the guard rows of
    a checkpoint without a guard."""
    spec = InputSpec(seed=ctx.seed)
    out = [Condition("sensor_faults", f"none | {r}", "none", spec, None, r)
           for r in ("unguarded", "guard")]
    for text in ctx.values or DEFAULT_FAULTS:
        fault = text if isinstance(text, FaultSpec) else FaultSpec.parse(text)
        if not set(fault.channels) & set(ctx.sensors):
            continue  # the student reads none of the fault's sensors
        out += [Condition("sensor_faults", f"{fault} | {r}", str(fault), spec, fault, r)
                for r in REMOVALS]
    return out


register_scenario(Scenario("token_removal", "Random token removal at test time",
                           "test mask ratio", _token_removal, plot=False))
register_scenario(Scenario("sensor_removal", "One sensor removed entirely", "removed sensor",
                           _sensor_removal))
register_scenario(Scenario("dead_joints", "Dead joint encoders (q and q̇ removed)",
                           "dead joints k", _dead_joints))
register_scenario(Scenario("history", "History window T (no masking)", "history T",
                           _history))
register_scenario(Scenario("dummy_tokens", "Random dummy tokens appended at test time",
                           "dummy tokens", _dummy_tokens))
register_scenario(Scenario("mask_matrix", "Train mask ratios (stage 1 x stage 2)",
                           "stage-2 mask ratio", _token_removal))
register_scenario(Scenario("sensor_faults", "Sensor faults: unguarded, oracle and guard",
                           "fault", _sensor_faults, plot=False))


@dataclass(frozen=True)
class Suite:
    """A named evaluation budget.

    Args:
        name: registry key (``--suite``).
        trials: episodes per (policy, condition), spread evenly over terrains x levels.
        terrains: terrain types.
        levels: difficulty levels.
        episode_length_s: episode time limit (s).
        num_envs: environments simulated together (trials run in rounds of this many).
        values: scenario name -> sweep values (empty tuple for sensor_removal: every sensor).
    """

    name: str
    trials: int
    terrains: tuple[str, ...]
    levels: tuple[int, ...]
    episode_length_s: float
    num_envs: int
    values: dict[str, tuple] = field(default_factory=dict)

    @property
    def scenarios(self) -> tuple[str, ...]:
        return tuple(self.values)


SUITES: dict[str, Suite] = {
    # The paper: 5000 trials over the five terrains and their levels, every sweep value.
    "paper": Suite(
        "paper", trials=5000, terrains=PAPER_TERRAINS, levels=tuple(range(10)), episode_length_s=20.0,
        num_envs=250,
        values={"token_removal": (0.0, 0.25, 0.5), "sensor_removal": (),
                "dead_joints": (0, 1, 2, 3, 4, 5, 6), "history": (3, 5, 7, 10, 15, 20),
                "mask_matrix": (0.0, 0.25, 0.5), "dummy_tokens": (0, 64, 256)}),
    # `make demo`: a few minutes on two CPU cores with the cpu MSTA preset.
    "quick": Suite(
        "quick", trials=5, terrains=PAPER_TERRAINS, levels=(1,), episode_length_s=3.0, num_envs=50,
        values={"token_removal": (0.0, 0.25, 0.5), "sensor_removal": (),
                "dead_joints": (0, 3, 6), "history": (3, 7, 15, 20),
                "mask_matrix": (0.0, 0.25, 0.5), "dummy_tokens": (0, 256)}),
}


def get_suite(name: str) -> Suite:
    """Registered suite ``name``; the error lists the known names."""
    try:
        return SUITES[name]
    except KeyError:
        raise KeyError(f"unknown suite {name!r}; known suites: {sorted(SUITES)}") from None


def build_conditions(scenarios: Sequence[str], suite: Suite, sensors: Sequence[str],
                     seed: int, values: dict[str, tuple] | None = None) -> list[Condition]:
    """Every condition of ``scenarios`` for a student reading ``sensors``.

    Args:
        scenarios: registry names, in output order.
        suite: supplies the sweep values (else the paper suite's; else the scenario's own
            default, e.g. sensor_faults').
        sensors: the student's input sensors.
        seed: the evaluation seed.
        values: scenario name -> sweep values that replace the suite's (msta-eval's
            ``--faults``).
    """
    out: dict[str, Condition] = {}
    for name in scenarios:
        scenario = get_scenario(name)
        sweep = (values or {}).get(name) or suite.values.get(
            name, SUITES["paper"].values.get(name, ()))
        for cond in scenario.build(ScenarioContext(tuple(sensors), tuple(sweep), seed)):
            out.setdefault(cond.key, cond)  # mask_matrix reuses the token_removal conditions
    return list(out.values())


#: config fields that do not change any number (left out of metrics.json)
_NOT_RESULTS = ("output_dir", "progress", "video", "video_s", "nthread", "resume", "max_minutes")


def split_csv(text: str) -> list[str]:
    """The non-empty, stripped items of a comma-separated option."""
    return [p.strip() for p in str(text).split(",") if p.strip()]


@dataclass
class TrialConfig:
    """Which trials an evaluation runs: msta-eval's and msta-correct's shared options.

    A *trial* is one episode of one robot on a pinned (terrain, level) tile; trial i runs
    on terrain ``i mod n_terrains`` at level ``levels[(i // n_terrains) mod n_levels]``
    (msta.eval.metrics.TrialLayout). Options left at 0 / empty take the suite's value.
    """

    suite: str = "quick"
    """budget that fills the options left at 0 / empty: quick (5 trials = one 3 s episode
    per paper terrain at level 1) or paper (5000 trials of 20 s over the five terrains and
    levels 0-9); see docs/eval.md."""
    trials: int = 0
    """episodes per (policy, condition), spread evenly over terrains x levels; 0 = the
    suite's."""
    terrains: str = ""
    """comma-separated terrain types; empty = the suite's (the paper's five)."""
    levels: str = ""
    """comma-separated terrain levels (0-9); empty = the suite's."""
    episode_length_s: float = 0.0
    """episode time limit (s); 0 = the suite's."""
    num_envs: int = 0
    """robots simulated together (trials run in rounds of this many); 0 = the suite's."""
    seed: int = 0
    """seeds the trials (tiles are pinned; spawns, commands, noise, pushes) and the
    students' test-time masks."""
    robot: str = ""
    """the simulated robot: a shipped robot's name or a .toml spec file's path (as
    --env.robot, docs/robots.md); empty = msta-eval: the robot the evaluated checkpoints were
    trained on (the A1 for teachers alone); msta-correct: the rounds' --env.robot."""
    noise: bool = True
    """observation noise on."""
    randomization: bool = True
    """domain randomization (dynamics, pushes, latency) on."""
    heading_commands: bool = True
    """yaw-rate command steers to a sampled heading (paper); false samples the yaw rate
    directly (then command sequences do not depend on the policy at all)."""
    num_threads: int = 1
    """torch threads while evaluating (figures are bit-identical for the same value)."""
    nthread: int = 2
    """MuJoCo rollout threads (do not change any figure; 0 = one per CPU core)."""

    def __post_init__(self) -> None:
        suite = get_suite(self.suite)
        self.terrain_list = split_csv(self.terrains) or list(suite.terrains)
        for t in self.terrain_list:
            if t not in TERRAIN_TYPES:
                raise ValueError(f"unknown terrain {t!r}; known terrains: {list(TERRAIN_TYPES)}")
        try:
            self.level_list = [int(v) for v in split_csv(self.levels)] or list(suite.levels)
        except ValueError:
            raise ValueError(f"--levels {self.levels!r} must be comma-separated integers") \
                from None
        bad = [lv for lv in self.level_list if not 0 <= lv < TerrainConfig().num_levels]
        if bad:
            raise ValueError(f"level {bad[0]} out of range [0, {TerrainConfig().num_levels})")
        check_at_least(self, 0, "trials", "num_envs", "episode_length_s")  # 0: the suite's
        self.num_trials = self.trials or suite.trials
        self.episode = self.episode_length_s or suite.episode_length_s
        self.envs = self.num_envs or suite.num_envs
        check_at_least(self, 1, "num_threads")
        check_sizes(self.envs, self.episode, self.nthread)
        #: the simulated robot's name (``robot``'s; the A1 while ``robot`` is empty)
        self.robot_name = load_sim_robot(self.robot, "robot").name if self.robot \
            else LEGACY_ROBOT

    def layout(self) -> TrialLayout:
        """The trial layout these options describe."""
        return TrialLayout(tuple(self.terrain_list), tuple(self.level_list), self.num_trials)

    def resolved(self) -> dict[str, Any]:
        """The effective configuration as stored with the figures (fields that change no
        number left out)."""
        d = {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()
             if k not in _NOT_RESULTS}  # JSON-shaped: equal to itself read back
        d.update(trials=self.num_trials, terrains=self.terrain_list, levels=self.level_list,
                 episode_length_s=self.episode, num_envs=self.envs, robot=self.robot_name)
        return d
