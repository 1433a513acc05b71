"""Command-line parsing shared by ``msta-train`` and ``msta-correct``."""

from __future__ import annotations

import dataclasses
import re
import sys
from collections.abc import Sequence
from dataclasses import replace

from msta.data.cli import parse_config, usage_error
from msta.data.errors import DatasetError, DirectoryLockedError
from msta.policies.checkpoint import CheckpointError
from msta.policies.config import PolicyConfig
from msta.policies.registry import register_builtin_configs, registered_policies
from msta.train.push import PushError

_PRESET = re.compile(r"^--policy\.preset(?:=(.*))?$")


def parse_cli[T](config_class: type[T], argv: Sequence[str] | None, prog: str,
                 aliases: dict[str, str] | None = None) -> T:
    """:func:`msta.data.cli.parse_config` plus two conveniences for a ``policy`` field that
    configures a new student (a :class:`PolicyConfig`; a ``--policy.path`` field is parsed as is).

    ``--policy.preset=<name>`` starts from a named preset (``MSTAConfig.from_preset``);
    ``--policy.<field>=...`` flags given explicitly still override it. Without
    ``--policy.type`` but with other ``--policy.*`` flags, ``--policy.type=msta`` is implied.
    Unknown options and invalid values exit 2 with a one-line message.

    Args:
        config_class: a draccus dataclass with a ``policy: PolicyConfig`` field.
        argv: arguments (default ``sys.argv[1:]``).
        prog: program name for the usage message.
        aliases: nested option -> the top-level option that decides it (parse_config).
    """
    args = list(sys.argv[1:] if argv is None else argv)
    register_types(args)
    if not builds_a_policy(config_class):  # --policy.path (a trained student): plain parsing
        return parse_config(config_class, args, prog, aliases=aliases)
    preset, rest = None, []
    for i, a in enumerate(args):
        m = _PRESET.match(a)
        if m and m.group(1) is None and i + 1 < len(args):
            raise usage_error(f"{prog}: error: write --policy.preset=<name> (with '=')")
        if m:
            preset = m.group(1)
        else:
            rest.append(a)
    policy_flags = [a for a in rest if a.startswith("--policy.")]
    if policy_flags and not any(a.startswith("--policy.type") for a in policy_flags):
        rest.insert(0, "--policy.type=msta")
    cfg = parse_config(config_class, rest, prog, extra_options=[("--policy.preset", (
        "start the policy config from a named preset (msta and the baselines: paper, cpu, "
        "tiny); explicit --policy.<field> flags still override it"))], aliases=aliases)
    if preset is not None:
        explicit = {a.split("=", 1)[0][len("--policy."):] for a in policy_flags} - {"type"}
        policy = cfg.policy  # type: ignore[attr-defined]
        try:
            new = type(policy).from_preset(preset, **{k: getattr(policy, k) for k in explicit})
        except (KeyError, ValueError) as e:
            raise usage_error(f"{prog}: error: {e.args[0]}") from None
        cfg = replace(cfg, policy=new)  # type: ignore[type-var]
    return cfg


def register_types(args: Sequence[str]) -> None:
    """Register the policy types a command line can name before it is parsed: the built-in
    configs (no torch, so ``--help`` answers at once), and every registered student's (their
    models imported) when ``args`` name a type those configs do not or read a config file."""
    register_builtin_configs()
    known = PolicyConfig.get_known_choices()
    named = [b if a == "--policy.type" else a.partition("=")[2]
             for a, b in zip(args, [*args[1:], ""]) if a.partition("=")[0] == "--policy.type"]
    if any(n not in known for n in named) or any(a.startswith("--config_path") for a in args):
        registered_policies()


def builds_a_policy(config_class: type) -> bool:
    """Whether ``config_class.policy`` configures a new student (``--policy.type``), not a
    trained one (``--policy.path``)."""
    f = {f.name: f for f in dataclasses.fields(config_class)}.get("policy")
    return f is not None and f.default_factory is not dataclasses.MISSING and isinstance(
        f.default_factory(), PolicyConfig)


#: Errors a user's input causes (a damaged dataset, a locked directory, a bad checkpoint or
#: value, a learning rate the loss diverges at): the CLIs print them as one line naming the
#: file, without a traceback.
USER_ERRORS = (PushError, DatasetError, DirectoryLockedError, CheckpointError,
               FileNotFoundError, FileExistsError, ValueError, FloatingPointError)
