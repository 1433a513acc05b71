"""The command-line layer every msta console script parses its config with.

:func:`parse_config` is draccus parsing (typed dataclass configs, ``--a.b.c=value``, an
unknown key is an error) plus what a user expects of a command line:

* ``--help`` shows every option with its description and default. The description is the
  field's entry in the ``Args:`` block of its dataclass docstring (the public API's
  documentation), so the two never drift apart; the dataclass docstring
  dumps and draccus' "Config file for <group>" lines are left out.
* A misspelled option exits 2 with one line and the closest known options
  ("did you mean --steps?") instead of a page of usage.
* An invalid value exits 2 with one line naming the field and the reason, no traceback.
* Spelling a command line the argparse way works too: ``--move-tag`` for ``--move_tag``, a
  bare boolean flag (``--overwrite``) for ``--overwrite=true``, and, for a command that names
  ``positionals``, leading bare words for those fields (``msta-hub pull SPEC DEST``).
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import difflib
import functools
import inspect
import itertools
import re
import sys
import textwrap
from collections.abc import Callable, Sequence
from typing import Any, NoReturn

import draccus
import yaml
from draccus.wrappers.field_metavar import get_metavar

from msta.data.cli_values import dataclasses_of, field_types, prepare_values

#: Errors that mean "a bad value on the command line" (draccus wraps ours).
VALUE_ERRORS = (draccus.utils.DecodingError, draccus.utils.ParsingError, ValueError, KeyError,
                TypeError, OSError, yaml.YAMLError)

_ENTRY = re.compile(r"^(\s*)(\w+(?:,\s*\w+)*)(?:\s*\([^)]*\))?:\s*(.*)$")


@functools.cache
def args_doc(cls: type) -> dict[str, str]:
    """Field name -> description from the ``Args:`` (or ``Attributes:``) blocks of ``cls``
    and its bases, or from a docstring right under the field (a subclass's entry wins),
    whitespace collapsed to one line."""
    out: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        # a leading newline: a docstring that starts with "Args:" keeps its entries indented
        doc = inspect.cleandoc("\n" + (klass.__dict__.get("__doc__") or ""))
        out.update(_parse_args_block(doc))
        out.update(_field_docstrings(klass))
    return out


def _field_docstrings(cls: type) -> dict[str, str]:
    """``x: int = 0`` followed by a string literal: that string documents ``x``."""
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
    except (OSError, TypeError, SyntaxError):
        return {}
    body = tree.body[0].body if tree.body and isinstance(tree.body[0], ast.ClassDef) else []
    out = {}
    for node, nxt in itertools.pairwise(body):
        if (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)
                and isinstance(nxt, ast.Expr) and isinstance(nxt.value, ast.Constant)
                and isinstance(nxt.value.value, str)):
            out[node.target.id] = " ".join(nxt.value.value.split())
    return out


def _parse_args_block(doc: str) -> dict[str, str]:
    out: dict[str, str] = {}
    lines = doc.splitlines()
    i = 0
    while i < len(lines):
        if lines[i].strip() not in ("Args:", "Attributes:"):
            i += 1
            continue
        base = len(lines[i]) - len(lines[i].lstrip())
        i += 1
        indent, names = None, []
        while i < len(lines):
            line = lines[i]
            depth = len(line) - len(line.lstrip())
            if line.strip() and depth <= base:
                break  # the block ended (the next section or text)
            m = _ENTRY.match(line)
            if m and (indent is None or len(m.group(1)) == indent):
                indent, names = len(m.group(1)), [n.strip() for n in m.group(2).split(",")]
                for name in names:
                    out[name] = m.group(3).strip()
            elif names and line.strip():
                for name in names:
                    out[name] = f"{out[name]} {line.strip()}".strip()
            i += 1
    return out


def field_help(config_class: type, dest: str) -> str | None:
    """Description of the option ``--<dest>`` (``env.terrain.types``) from the docstrings."""
    classes, *path = [config_class], *dest.split(".")
    for part in path[:-1]:
        nested = []
        for cls in classes:
            if dataclasses.is_dataclass(cls):
                tp = field_types(cls).get(part)
                if tp is not None:
                    nested += dataclasses_of(tp)
        classes = nested
    for cls in classes:
        doc = args_doc(cls).get(path[-1])
        if doc:
            return doc
    return None


def _format_default(value: Any) -> str:
    if isinstance(value, bool):
        return str(value).lower()
    if value is None:
        return "null"
    if isinstance(value, (tuple, list)):
        return "[" + ",".join(_format_default(v) for v in value) + "]" if value else "[]"
    if isinstance(value, str):
        return repr(value) if value == "" else value
    return str(value)


class HelpFormatter(argparse.MetavarTypeHelpFormatter):
    """Type names as metavars (``--steps int``); descriptions and defaults come from
    :func:`document`, so no automatic "(default: ...)" is added."""

    def _format_args(self, action: argparse.Action, default_metavar: str) -> str:
        if action.choices or action.type is None:
            return super()._format_args(action, default_metavar)
        return get_metavar(action.type) or super()._format_args(action, default_metavar)

    def _get_default_metavar_for_optional(self, action: argparse.Action) -> str:
        return getattr(action.type, "__name__", None) or "value"


_UNKNOWN = object()


def _value_at(instance: Any, dest: str, fallback: Any, *, through_choices: bool) -> Any:
    """The value at ``dest`` (``teacher.path``) in the default-built config ``instance``;
    ``fallback`` for a config without full defaults (``_UNKNOWN``), a field it does not
    have, or, unless ``through_choices``, a path through a choice type (``policy.*``: its
    options belong to several registered types, the built default is only one of them)."""
    obj = instance
    try:
        for part in dest.split("."):
            if obj is _UNKNOWN or (not through_choices
                                   and isinstance(obj, draccus.ChoiceRegistry)):
                return fallback
            obj = getattr(obj, part)
    except Exception:  # noqa: BLE001 - no such field, or a property that cannot answer
        return fallback
    return obj


class _FactoryDefaults:
    """The nested groups of a config that cannot be built without arguments, each as its
    ``default_factory`` builds it (``teacher``: the shipped PPO teacher, not the class's "")."""

    def __init__(self, config_class: type) -> None:
        self.fields = {f.name: f for f in dataclasses.fields(config_class)}

    def __getattr__(self, name: str) -> Any:
        f = self.__dict__.get("fields", {}).get(name)
        if f is None or f.default_factory is dataclasses.MISSING:
            raise AttributeError(name)
        return f.default_factory()


def _default_instance(config_class: type) -> Any:
    """A default-constructed config; its nested groups' defaults when it has required
    fields or checks that fail on the defaults; ``_UNKNOWN`` for a class without fields."""
    try:
        return config_class()
    except Exception:  # noqa: BLE001 - a config without full defaults
        if dataclasses.is_dataclass(config_class):
            return _FactoryDefaults(config_class)
        return _UNKNOWN


def document(parser: argparse.ArgumentParser, config_class: type) -> None:
    """Rewrite the help of draccus' parser: descriptions and defaults on every option."""
    actions = {id(a): a for a in parser._actions}  # draccus also keeps some only in groups
    actions.update({id(a): a for g in parser._action_groups for a in g._group_actions})
    # a nested group's defaults as the command builds them: a default_factory may differ
    # from the group class's own defaults, which are all draccus knows
    instance = _default_instance(config_class)
    for action in actions.values():
        if not action.option_strings or action.dest in ("help", draccus.utils.CONFIG_ARG):
            continue
        if isinstance(action.help, str) and action.help.startswith("Config file for "):
            action.help = argparse.SUPPRESS  # draccus' per-group config-file options
            continue
        default = action.default
        if action.dest.endswith(".type") and action.choices:  # a draccus choice type
            group = action.dest[:-len(".type")]
            text = f"which registered {group} type to build"
            default = _value_at(instance, action.dest, None, through_choices=True)
        else:
            text = field_help(config_class, action.dest) or (action.help or "").strip() or None
            if "." in action.dest:  # top-level options: draccus' own default
                default = _value_at(instance, action.dest, default, through_choices=False)
        parts = [text] if text else []
        if action.choices:
            parts.append("(one of: " + ", ".join(map(str, action.choices)) + ")")
        if not dataclasses.is_dataclass(default):
            parts.append(f"(default: {_format_default(default)})")
        action.help = " ".join(parts).replace("%", "%%")
    for group in parser._action_groups:
        group.description = None  # the dataclass docstring: its Args are on the options now


def _one_line_error(parser: argparse.ArgumentParser, prog: str) -> Callable[[str], NoReturn]:
    known = [s for a in parser._actions for s in a.option_strings
             if a.help is not argparse.SUPPRESS and a.dest != "help"]

    def error(message: str) -> NoReturn:
        m = re.match(r"unrecognized arguments: (.*)", message)
        if m:
            bad = [a.split("=", 1)[0] for a in m.group(1).split() if a.startswith("-")]
            hints = []
            for opt in bad:
                close = difflib.get_close_matches(opt, known, n=3, cutoff=0.6)
                hints.append(f"{opt}" + (f" (did you mean {' or '.join(close)}?)" if close
                                         else ""))
            message = "unknown option " + ", ".join(hints or [m.group(1)])
        raise usage_error(f"{prog}: error: {message}; see {prog} --help")

    return error


def parse_config[T](config_class: type[T], argv: Sequence[str] | None, prog: str,
                    extra_options: Sequence[tuple[str, str]] = (),
                    aliases: dict[str, str] | None = None,
                    positionals: Sequence[str] = ()) -> T:
    """Parse ``argv`` (default ``sys.argv[1:]``) into ``config_class`` (see the module doc).

    Args:
        config_class: a draccus dataclass.
        argv: command-line arguments.
        prog: program name shown in help and errors.
        extra_options: ``(flag, help)`` of options the caller consumes itself before
            parsing (e.g. ``--policy.preset``), listed in ``--help`` only.
        aliases: nested option -> the top-level option that decides it (``env.seed`` ->
            ``seed`` where the command sets ``env.seed`` from ``seed``): the nested flag is
            read as the top-level one, and giving both is an error, so an option the user
            gave is never silently overridden.
        positionals: fields that bare words on the command line fill, in order
            (``SPEC DEST`` for ``--spec=SPEC --dest=DEST``); listed in the usage line.

    Raises:
        SystemExit: 0 after ``--help``; 2 with a one-line message for an unknown option or
            an invalid value.
    """
    args = _resolve_aliases(list(sys.argv[1:] if argv is None else argv), aliases or {}, prog)
    _check_groups(config_class, args, prog)
    try:
        wrapper = draccus.argparsing.ArgumentParser(config_class, prog=prog,
                                                    formatter_class=HelpFormatter)
        args = _argparse_spellings(args, wrapper.parser, positionals, prog)
        args = prepare_values(args, wrapper.parser, config_class)
        if "-h" in args or "--help" in args:
            document(wrapper.parser, config_class)
            _document_positionals(wrapper.parser, positionals)
        for a in wrapper.parser._actions:
            if a.dest in (aliases or {}):
                a.help = f"the same as --{aliases[a.dest]} (which see)"  # type: ignore[index]
        for flag, text in extra_options:
            wrapper.parser.add_argument(flag, metavar="str", default=argparse.SUPPRESS,
                                        help=text.replace("%", "%%"))
        words = "".join(f" {name.upper()}" for name in positionals)
        wrapper.parser.usage = f"{prog} [-h]{words} [--<option>=<value> ...]"
        wrapper.parser.error = _one_line_error(wrapper.parser, prog)  # type: ignore[method-assign]
        return wrapper.parse_args(args)
    except VALUE_ERRORS as e:
        raise usage_error(f"{prog}: error: {' '.join(describe(e).split())}") from None


def _document_positionals(parser: argparse.ArgumentParser, positionals: Sequence[str]) -> None:
    for a in parser._actions:
        if a.dest in positionals and isinstance(a.help, str):
            k = positionals.index(a.dest) + 1
            a.help = re.sub(r"\(default: [^)]*\)$", f"(required: argument {k}, or --{a.dest})",
                            a.help)


_BOOL_WORDS = frozenset({"true", "false", "yes", "no", "on", "off", "1", "0"})


def _argparse_spellings(args: list[str], parser: argparse.ArgumentParser,
                        positionals: Sequence[str], prog: str) -> list[str]:
    """``--a-b`` -> ``--a_b`` (when only the latter exists), a bare boolean flag ->
    ``--flag=true``, bare words -> the ``positionals`` fields in order."""
    options = {s: a for a in parser._actions for s in a.option_strings}
    out: list[str] = []
    words = iter(positionals)
    i = 0
    while i < len(args):
        arg = args[i]
        i += 1
        if arg.startswith("--"):
            flag, sep, value = arg.partition("=")
            if flag not in options and flag[2:].replace("-", "_") != flag[2:]:
                underscored = "--" + flag[2:].replace("-", "_")
                flag = underscored if underscored in options else flag
            action = options.get(flag)
            if action is not None and action.type is bool and not sep and (
                    i == len(args) or args[i].lower() not in _BOOL_WORDS):
                sep, value = "=", "true"
            out.append(f"{flag}{sep}{value}")
            if action is not None and not sep and action.nargs != 0 and i < len(args):
                out.append(args[i])  # --option value
                i += 1
        elif arg.startswith("-") or not positionals:
            out.append(arg)
        else:
            name = next(words, None)
            if name is None:
                raise usage_error(f"{prog}: error: unexpected argument {arg!r} (takes "
                                  f"{' '.join(p.upper() for p in positionals)}); "
                                  f"see {prog} --help")
            out.append(f"--{name}={arg}")
    return out


def _check_groups(config_class: type, args: Sequence[str], prog: str) -> None:
    """``--policy=x`` where ``policy`` is a group of options (a nested config): one line
    naming the group's options instead of draccus' decoding error."""
    groups = {name: tp for name, tp in field_types(config_class).items() if dataclasses_of(tp)}
    for a in args:
        name = a[2:].partition("=")[0] if a.startswith("--") else None
        if name in groups:
            classes = dataclasses_of(groups[name])
            choices = getattr(classes[0], "get_known_choices", None)
            fields = sorted({f.name for c in classes for f in dataclasses.fields(c)})
            if choices is not None:
                hint = f"--{name}.type=<{'|'.join(choices())}> and --{name}.<field>=..."
            elif len(fields) == 1:
                hint = f"--{name}.{fields[0]}=..."
            else:
                hint = ", ".join(f"--{name}.{f}" for f in fields[:6]) + (
                    ", ..." if len(fields) > 6 else "")
            raise usage_error(f"{prog}: error: --{name} is a group of options; give "
                              f"{hint} (see {prog} --help)")


def _resolve_aliases(args: list[str], aliases: dict[str, str], prog: str) -> list[str]:
    given: dict[str, str] = {}
    out = []
    for a in args:
        flag, sep, value = a.partition("=")
        name = flag[2:] if flag.startswith("--") else None
        if name in aliases:
            target = aliases[name]
            if target in given.values() or any(x.partition("=")[0] == f"--{target}"
                                               for x in args):
                raise usage_error(f"{prog}: error: give --{target} or --{name}, not both "
                                  f"(--{target} sets {name})")
            given[name] = target
            a = f"--{target}{sep}{value}"
        out.append(a)
    return out


class UsageError(SystemExit):
    """Exit status 2 (argparse's for a bad command line); ``str()`` is the message."""

    def __init__(self, message: str) -> None:
        super().__init__(2)
        self.message = message

    def __str__(self) -> str:
        return self.message


def usage_error(message: str) -> UsageError:
    """Print ``message`` to stderr and return the exception to raise (exit status 2)."""
    sys.stderr.write(message + "\n")
    return UsageError(message)


def describe(e: BaseException) -> str:
    """One line for a parsing error: the field or class draccus names, then the innermost
    reason (our ``__post_init__`` checks raise inside draccus' wrappers)."""
    def inner(x: BaseException) -> BaseException | None:  # ``raise ... from None`` ends it
        if x.__cause__ is not None:
            return x.__cause__
        if x.__suppress_context__:
            return None
        return x.__context__

    where, root = "", e
    while (nxt := inner(root)) is not None:
        text = str(root)
        if text.startswith("Couldn't instantiate class "):
            where = text.split()[3] + ": "
        root = nxt
    msg = root.args[0] if isinstance(root, KeyError) and root.args else root
    if root is e:
        return f"{msg}"
    return f"{where}{msg}" if where else f"{e} ({type(root).__name__}: {msg})"
