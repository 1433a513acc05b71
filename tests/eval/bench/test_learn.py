"""make bench-learn's learners: each name stands for the student config it trains."""

from __future__ import annotations

from msta.eval.apps.demo import DemoConfig
from msta.eval.bench.learn import LEARNERS, BenchLearnConfig, policy_config
from msta.policies.msta import MSTAConfig


def test_msta_demo_is_the_demos_student_and_msta_cpu_the_presets():
    """msta_demo trains the demo's (and the reference study's) MSTA: the cpu preset at the
    demo's window; msta_cpu the cpu preset at its own T = 15."""
    demo = policy_config("msta_demo")
    assert demo.history == DemoConfig().history == 4
    assert demo.tokens == MSTAConfig.from_preset("cpu").tokens == "sensor"
    assert policy_config("msta_cpu").history == 15
    assert policy_config("gru").type == "gru"
    assert BenchLearnConfig().names() == list(LEARNERS)
