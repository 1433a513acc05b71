"""Contract of every draccus console script: documented --help, one-line errors (exit 2)."""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import pytest

from msta.collect.record import main as collect_main
from msta.collect.simulate import main as sim_main
from msta.data.cli import args_doc, field_help, parse_config
from msta.data.hub_cli import COMMANDS as HUB_COMMANDS
from msta.data.hub_cli import main as hub_main
from msta.eval.apps.compare import main as compare_main
from msta.eval.apps.demo import main as demo_main
from msta.eval.bench.data import main as bench_data_main
from msta.eval.bench.deploy import main as bench_deploy_main
from msta.eval.bench.learn import main as bench_learn_main
from msta.eval.bench.sim import main as bench_sim_main
from msta.eval.bench.train import main as bench_train_main
from msta.eval.evaluate import main as eval_main
from msta.eval.label_check import main as label_check_main
from msta.eval.report import main as report_main
from msta.eval.teacher_report import main as teacher_report_main
from msta.policies.export_cli import main as export_main
from msta.train.finetune import main as finetune_main
from msta.train.offline import main as train_main
from msta.train.online import main as correct_main
from msta.train.teacher.cli import main as train_teacher_main

#: console script -> (entry point, an option it has, a bad value for an option)
SCRIPTS = {
    "msta-train": (train_main, "--steps", "--steps=abc"),
    "msta-correct": (correct_main, "--rounds", "--env.collision=fastt"),
    "msta-finetune": (finetune_main, "--trainable", "--history=0"),
    "msta-train-teacher": (train_teacher_main, "--seed", "--ppo.init_std=0"),
    "msta-collect": (collect_main, "--episodes", "--episodes=0"),
    "msta-eval": (eval_main, "--trials", "--terrains=lava"),
    "msta-compare": (compare_main, "--preset", "--collect_num_envs=x"),
    "msta-sim": (sim_main, "--seconds", "--env.num_envs=-1"),
    "python -m msta.eval.apps.demo": (demo_main, "--rounds", "--rounds=-1"),
    "python -m msta.eval.bench.learn": (bench_learn_main, "--learners", "--learners=gpt"),
    "python -m msta.eval.bench.train": (bench_train_main, "--rounds", "--seconds=0"),
    "python -m msta.eval.bench.sim": (bench_sim_main, "--nthread", "--collision=fastt"),
    "python -m msta.eval.bench.data": (bench_data_main, "--frames", "--frames=0"),
    "python -m msta.eval.bench.deploy": (bench_deploy_main, "--preset", "--preset=huge"),
    "msta-export": (export_main, "--sensors", "--tolerance=0"),
    "python -m msta.eval.label_check": (label_check_main, "--student_seconds", "--num_envs=0"),
    "python -m msta.eval.report": (report_main, "--output_dir", "--metrics=/no/such/metrics.json"),
    "python -m msta.eval.teacher_report": (teacher_report_main, "--envs_per_tile", "--levels=3-12"),
}


def hub_command(command: str):
    """``msta-hub <command>`` as an entry point taking the rest of the command line."""
    return lambda argv: hub_main([command, *argv])


#: msta-hub's sub-commands, each parsed by the same layer as the scripts above
HUB = {
    "msta-hub serve": (hub_command("serve"), "--port", "--port=abc"),
    "msta-hub push": (hub_command("push"), "--tag", "--stage=abc"),
    "msta-hub push-dataset": (hub_command("push-dataset"), "--message", "--round=x"),
    "msta-hub pull": (hub_command("pull"), "--overwrite", "--overwrite=maybe"),
    "msta-hub versions": (hub_command("versions"), "--json", "--dataset=maybe"),
}
assert {k.split()[1] for k in HUB} == set(HUB_COMMANDS)
SCRIPTS.update(HUB)


def options(help_text: str) -> dict[str, str]:
    """Option flag -> its help text (the rest of its line and its continuation lines)."""
    out: dict[str, str] = {}
    flag = None
    for line in help_text.splitlines():
        m = re.match(r"^  (-h, )?(--[\w.]+)(?: \S+(?: \S+)*)?(?:\s{2,}(.*))?$", line)
        if m:
            flag = m.group(2)
            out[flag] = (m.group(3) or "").strip()
        elif flag and line.startswith("   ") and line.strip():
            out[flag] = f"{out[flag]} {line.strip()}"
        elif not line.strip() or not line.startswith(" "):
            flag = None
    return out


@pytest.mark.parametrize("prog", SCRIPTS)
def test_help_describes_every_option_and_errors_are_one_line(prog, capsys):
    main, known, bad_value = SCRIPTS[prog]
    with pytest.raises(SystemExit) as e:
        main(["--help"])
    assert e.value.code == 0
    text = capsys.readouterr().out
    opts = options(text)
    assert known in opts and len(opts) >= 4  # -h, --config_path and the config's own
    for flag, desc in opts.items():
        words = re.sub(r"\(default: .*?\)", "", desc).strip()
        assert words, f"{prog} {flag}: no description"
        assert "def " not in desc and "Config file for" not in desc, f"{prog} {flag}: {desc}"
    assert "Args:" not in text and len(text.splitlines()[0]) < 100  # short usage line

    typo = known[:-1] + known[-1].upper() + "x"  # --stepsx-like: close to a real option
    with pytest.raises(SystemExit) as e:
        main([f"{typo}=1"])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"did you mean {known}" in err, err

    with pytest.raises(SystemExit) as e:
        main([bad_value])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith(f"{prog}: error: "), err


def test_policy_help_lists_types_presets_and_the_chosen_type_fields(capsys):
    with pytest.raises(SystemExit):
        train_main(["--policy.type=gru", "--help"])
    opts = options(capsys.readouterr().out)
    assert "gru" in opts["--policy.type"] and "(default: msta)" in opts["--policy.type"]
    assert "paper, cpu, tiny" in opts["--policy.preset"]
    assert opts["--policy.hidden_dim"]  # a GRU field, described


@dataclass
class Inner:
    """Args:
        kp, kd: two gains
            on one entry.
    """

    depth: int = 3
    """a field docstring."""
    kp: float = 1.0
    kd: float = 2.0

    def gains(self) -> tuple[float, float]:
        """(see Outer.label)"""
        return self.kp, self.kd


@dataclass
class Outer:
    """Outer config.

    Args:
        name: what it is called.
        inner: nested options.
    """

    name: str = "x"
    inner: Inner = field(default_factory=Inner)

    def label(self) -> str:
        """(draccus reads a docstring's last Args entry as a field and the closing quotes as
        the start of its docstring, which must end somewhere below.)"""
        return self.name


def test_descriptions_come_from_args_blocks_and_field_docstrings():
    assert args_doc(Inner) == {"kp": "two gains on one entry.", "kd": "two gains on one entry.",
                               "depth": "a field docstring."}
    assert field_help(Outer, "inner.depth") == "a field docstring."
    assert field_help(Outer, "name") == "what it is called."
    assert field_help(Outer, "nope") is None
    cfg = parse_config(Outer, ["--inner.kd=5", "--name=y"], "prog")
    assert cfg == Outer(name="y", inner=Inner(kd=5.0))


def inner_kd_75() -> Inner:
    return Inner(kd=7.5)


@dataclass
class Factory:
    """Args:
        inner: nested options, built by a factory that changes one of them.
    """

    inner: Inner = field(default_factory=inner_kd_75)

    def gains(self) -> tuple[float, float]:
        """(a docstring below the fields: see Outer.label)"""
        return self.inner.gains()


def test_help_shows_the_default_a_factory_builds_not_the_nested_class_default(capsys):
    with pytest.raises(SystemExit):
        parse_config(Factory, ["--help"], "prog")
    opts = options(capsys.readouterr().out)
    assert "(default: 7.5)" in opts["--inner.kd"]  # Inner's own default is 2.0
    assert "(default: 1.0)" in opts["--inner.kp"]
    # the demo: its teacher is the shipped PPO teacher, not TeacherConfig's own gait default
    with pytest.raises(SystemExit):
        demo_main(["--help"])
    opts = options(capsys.readouterr().out)
    assert "(default: rma)" in opts["--teacher.type"]
    assert "rma_ppo" in opts["--teacher.path"]


def test_a_nested_option_the_command_sets_itself_is_read_not_overridden():
    """msta-collect sets env.episode_length_s / env.seed / env.num_envs from its own
    top-level options: the nested flags mean the same, and both at once is an error."""
    from msta.collect.record import parse_config as collect_config

    cfg = collect_config(["--env.episode_length_s=0.2", "--env.seed=7", "--env.num_envs=3"])
    assert (cfg.episode_length_s, cfg.seed, cfg.num_envs) == (0.2, 7, 3)
    with pytest.raises(SystemExit, match="give --seed or --env.seed, not both") as e:
        collect_config(["--seed=1", "--env.seed=7"])
    assert e.value.code == 2


@pytest.mark.parametrize(("main", "arg", "hint"), [
    (correct_main, "--policy=ckpt", "--policy.path=..."),
    (train_main, "--policy=gru", "--policy.type=<msta|"),
    (sim_main, "--teacher=gait", "--teacher.type"),
])
def test_a_group_given_a_value_names_its_options(main, arg, hint, capsys):
    """``--policy=x`` where --policy is a group of options (LeRobot's --policy.path /
    --policy.type) is one line naming the group's options, not a decoding error."""
    with pytest.raises(SystemExit) as e:
        main([arg])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "is a group of options" in err and hint in err, err


@dataclass
class _Checked:
    level: str = "0"

    def __post_init__(self) -> None:
        try:
            int(self.level)
        except ValueError:
            raise ValueError(f"--level {self.level!r} must be an integer") from None


def test_an_error_raised_from_none_is_shown_as_raised_not_its_hidden_cause(capsys):
    """``raise ValueError(ours) from None`` inside a check: the line is ours, not the
    suppressed exception's (Python's own wording about int())."""
    with pytest.raises(SystemExit) as exc:
        parse_config(_Checked, ["--level", "x"], "prog")
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err == "prog: error: _Checked: --level 'x' must be an integer", err


@dataclass
class _Text:
    """Args:
        root: a folder.
        task: a text.
        n: a number.
        sensors: names.
    """

    root: str = "out"
    task: str = ""
    n: int = 1
    sensors: tuple[str, ...] = ("a",)


@pytest.mark.parametrize("value", ["null", "~", "[a, b]", "{a: 1}", "yes", "bias:3:encoder:",
                                   "a: b", "'quoted'", 'say "hi"', "back\\slash", "1e3", "",
                                   "/tmp/x\U0001F642\u00e9"])
def test_a_text_option_is_taken_as_typed(value):
    """Values are YAML for draccus; a text option's value is not (null, yes, [a, b] and
    bias:3:encoder: were None, True, a list and a mapping)."""
    for argv in ([f"--root={value}"], ["--root", value]):
        cfg = parse_config(_Text, [*argv, "--n=3", "--sensors=[x, y]"], "prog")
        assert (cfg.root, cfg.n, cfg.sensors) == (value, 3, ("x", "y"))


@pytest.mark.parametrize("value", ["a\n---\nb", "tab\there", "bell\x07", "\udc80", "c1\x85",
                                   "line\u2028sep"])
@pytest.mark.parametrize("option", ["task", "sensors"])
def test_a_control_character_in_any_option_is_one_line(value, option, capsys):
    """A text option, and a list of names (a terrain or task name recorded into the dataset
    card)."""
    with pytest.raises(SystemExit) as e:
        parse_config(_Text, [f"--{option}={value}"], "prog")
    err = capsys.readouterr().err.strip()
    assert e.value.code == 2 and len(err.splitlines()) == 1
    assert err.startswith(f"prog: error: --{option} must be text without control characters")


@pytest.mark.parametrize("argv,says", [
    (["--n", "nan"], "--n=nan must be a finite number"),
    (["--n", "9" * 23], "must be within the 64-bit integers msta takes"),
    (["--sensors", "[a\nb]"], "--sensors must be text without control characters"),
])
def test_the_spaced_spelling_is_checked_as_the_equals_one(argv, says, capsys):
    """``--option value`` gets the checks of ``--option=value``."""
    with pytest.raises(SystemExit):
        parse_config(_Text, argv, "prog")
    assert says in capsys.readouterr().err
