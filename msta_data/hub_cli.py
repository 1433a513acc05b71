"""``msta-hub``: run a local hub server, push/pull checkpoints and datasets, list versions.

Each command parses its own typed config through :func:`msta.data.cli.parse_config` (every
option described in ``msta-hub <command> --help`` with its default; a bad option or value is
one line, exit 2). The client commands talk to HF_ENDPOINT with the token in HF_TOKEN (never
on the command line, so it stays out of shell history and process lists).
"""

from __future__ import annotations

import difflib
import json
import logging
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import httpx
from huggingface_hub.errors import HfHubHTTPError

from msta.data.cli import parse_config, usage_error
from msta.data.errors import DirectoryLockedError
from msta.data.hub_cards import CardInfo
from msta.data.hub_eval import EvalFigures, EvalJsonError, read_eval_json, read_json_input
from msta.data.hub_ids import HubError, endpoint_url
from msta.data.hub_pull import pull
from msta.data.hub_push import Pushed, push, push_dataset
from msta.data.hub_server import HubServer, ServerConfig
from msta.data.hub_server.protocol import Limits
from msta.data.hub_versions import versions

_EPILOG = """examples:
  msta-hub serve --root /srv/msta-hub --port 8008 --token_file /etc/msta-hub/tokens
  export HF_ENDPOINT=http://127.0.0.1:8008 HF_TOKEN=...   # then:
  msta-hub push runs/stage1 alice/msta-a1 --tag stage1-r0 --stage 1 --round 0
  msta-hub push-dataset data/a1-teacher alice/a1-teacher
  msta-hub pull alice/msta-a1@stage1-r0 ckpt/stage1
  msta-hub pull datasets/alice/a1-teacher@v3.0 data/a1-teacher
  msta-hub versions alice/msta-a1
"""
_LIMITS = Limits()


@dataclass
class ServeConfig:
    """Args:
        root: directory holding the repos and blobs (created when missing).
        host: interface to bind (127.0.0.1: this machine only).
        port: TCP port; 0 picks a free one (printed, and written to --port_file).
        token: users and their tokens, ``["NAME:SECRET", ...]`` (--token may be repeated);
            prefer --token_file, which keeps secrets out of the process list.
        token_file: file with one ``NAME:SECRET`` a line.
        org: organisations, ``["ORG:USER1,USER2", ...]`` (--org may be repeated); members
            may write in namespace ORG.
        lfs_threshold: upload files of at least this many bytes through Git LFS (clients need
            HF_HUB_DISABLE_XET=1); null: every file inline in its commit.
        public_url: base URL for links when the server is behind a proxy.
        port_file: write the bound port to this file.
        max_body_bytes: largest JSON request body; larger ones get 413 before they are read.
        max_anonymous_body_bytes: the same for requests without a token (validate-yaml).
        max_commit_bytes: largest commit body, inline files base64-encoded (use
            --lfs_threshold for bigger files).
        read_timeout: seconds a client may stay silent before it is dropped; a body must
            also average 1 KiB/s after that.
        header_timeout: seconds a request's line and headers may take in all, however paced.
        max_card_bytes: largest README.md YAML front matter the server parses.
        max_connections: requests served at once (headers read, answer not yet sent); more
            get 503.
        max_anonymous: of those, requests without a token (more get 429); the rest stay
            for users.
        max_anonymous_per_client: anonymous requests served at once from one IP address
            (more get 429).
        max_open_connections: open connections (idle, sending headers or served); more get 503.
        max_open_per_client: open connections from one IP address.
        max_user_connections: requests one user serves at once (an LFS upload counts for the
            user whose ticket it carries); more get 429, so other users keep their slots.
        max_user_body_bytes: bytes of request bodies one user (without a token: one address)
            has in progress at once; more get 429 (a principal's only request always passes).
        max_user_tickets: open LFS upload tickets of one user; a batch beyond gets 429.
        max_tickets: open LFS upload tickets in all; a batch beyond gets 503.
        verbose: log requests and progress (serve always logs requests).
    """

    root: Path | None = None
    host: str = "127.0.0.1"
    port: int = 0
    token: list[str] = field(default_factory=list)
    token_file: Path | None = None
    org: list[str] = field(default_factory=list)
    lfs_threshold: int | None = None
    public_url: str | None = None
    port_file: Path | None = None
    max_body_bytes: int = _LIMITS.max_body_bytes
    max_anonymous_body_bytes: int = _LIMITS.max_anonymous_body_bytes
    max_commit_bytes: int = _LIMITS.max_commit_bytes
    read_timeout: float = _LIMITS.read_timeout_s
    header_timeout: float = _LIMITS.header_timeout_s
    max_card_bytes: int = _LIMITS.max_card_bytes
    max_connections: int = _LIMITS.max_connections
    max_anonymous: int = _LIMITS.max_anonymous
    max_anonymous_per_client: int = _LIMITS.max_anonymous_per_client
    max_open_connections: int = _LIMITS.max_open_connections
    max_open_per_client: int = _LIMITS.max_open_per_client
    max_user_connections: int = _LIMITS.max_user_connections
    max_user_body_bytes: int = _LIMITS.max_user_body_bytes
    max_user_tickets: int = _LIMITS.max_user_tickets
    max_tickets: int = _LIMITS.max_tickets
    verbose: bool = False

    def __post_init__(self) -> None:
        if self.root is None:
            raise ValueError("--root is required (the directory holding the hub's data)")
        self.limits()  # the same checks as the server's
        if not 0 <= self.port < 65536:
            raise ValueError(f"port={self.port} must be in [0, 65535]")

    def limits(self) -> Limits:
        return Limits(max_body_bytes=self.max_body_bytes, max_anonymous_body_bytes=self.max_anonymous_body_bytes,
                      max_commit_bytes=self.max_commit_bytes, read_timeout_s=self.read_timeout,
                      header_timeout_s=self.header_timeout, max_card_bytes=self.max_card_bytes,
                      max_connections=self.max_connections, max_anonymous=self.max_anonymous,
                      max_anonymous_per_client=self.max_anonymous_per_client,
                      max_open_connections=self.max_open_connections,
                      max_open_per_client=self.max_open_per_client,
                      max_user_connections=self.max_user_connections,
                      max_user_body_bytes=self.max_user_body_bytes,
                      max_user_tickets=self.max_user_tickets, max_tickets=self.max_tickets)


@dataclass
class ClientConfig:
    """Args:
        endpoint: hub URL; empty: HF_ENDPOINT.
        verbose: log requests and progress.
    """

    endpoint: str = ""
    verbose: bool = False


def _required(**values: object) -> None:
    for name, value in values.items():
        if value is None or value == "":
            raise ValueError(f"{name.upper()} is required (see --help)")


@dataclass
class CardOptions(ClientConfig):
    """What the pushed commit's card (README.md front matter) records.

    Args:
        tag: tag for this version, e.g. stage1-r0.
        private: create the repo as private (only when it is created).
        message: commit message; null: "Upload <type> checkpoint <name> (<n> files)" (push-dataset:
            "Upload LeRobot dataset <name> (<episodes> episodes, <n> files)").
        dataset_repo: hub id of the training / source dataset.
        dataset_revision: commit sha or tag of that dataset.
        stage: training stage (1 offline, 2 online correction).
        round: correction round.
        base_model: hub id of the checkpoint this one was trained from (the card's
            base_model); null: the one train_config.json names, when it is a hub id.
        config_json: config to record; null: the checkpoint's config.json (without
            LeRobot's run settings such as device and push_to_hub).
        eval_json: figures for the card: msta-eval's metrics.json (push only: the student's
            tracking vs teacher, survival and total vs teacher per scenario and condition,
            with 95 % intervals and trial counts), ``{metric: number}`` or ``{row: {column:
            number}}``; anything else is an error.
    """

    tag: str | None = None
    private: bool = False
    message: str | None = None
    dataset_repo: str | None = None
    dataset_revision: str | None = None
    stage: int | None = None
    round: int | None = None
    base_model: str | None = None
    config_json: Path | None = None
    eval_json: Path | None = None


@dataclass
class PushConfig(CardOptions):
    """Args:
        checkpoint_dir: directory to push (config.json, model.safetensors, ...).
        repo_id: ``user/name`` of the model repo (created when missing).
        move_tag: move --tag when it already points to another commit.
        branch: branch to commit to (created from main when missing).
        eval_policy: the student of --eval_json (msta-eval's metrics.json) whose figures go
            on the card; empty: the one evaluated from this directory's files (or the only
            student in the file).
    """

    checkpoint_dir: Path | None = None
    repo_id: str = ""
    move_tag: bool = False
    branch: str = "main"
    eval_policy: str = ""

    def __post_init__(self) -> None:
        _required(checkpoint_dir=self.checkpoint_dir, repo_id=self.repo_id)


@dataclass
class PushDatasetConfig(CardOptions):
    """Args:
        root: LeRobot dataset root (holds meta/info.json).
        repo_id: ``user/name`` of the dataset repo (created when missing).
    """

    root: Path | None = None
    repo_id: str = ""

    def __post_init__(self) -> None:
        _required(root=self.root, repo_id=self.repo_id)


@dataclass
class PullConfig(ClientConfig):
    """Args:
        spec: ``[datasets/]user/name[@branch|tag|sha]``.
        dest: directory to create (it must not exist or be empty unless --overwrite).
        dataset: the repo is a dataset repo (as the ``datasets/`` prefix says).
        overwrite: replace DEST if it exists (only after a verified download).
    """

    spec: str = ""
    dest: Path | None = None
    dataset: bool = False
    overwrite: bool = False

    def __post_init__(self) -> None:
        _required(spec=self.spec, dest=self.dest)


@dataclass
class VersionsConfig(ClientConfig):
    """Args:
        repo_id: ``[datasets/]user/name``.
        dataset: the repo is a dataset repo.
        json: print JSON (every metric, the cards' front matter) instead of text lines.
        no_metrics: skip reading each commit's card (one request fewer per commit).
    """

    repo_id: str = ""
    dataset: bool = False
    json: bool = False
    no_metrics: bool = False

    def __post_init__(self) -> None:
        _required(repo_id=self.repo_id)


def _serve(cfg: ServeConfig) -> int:
    if not cfg.token and cfg.token_file is None:
        print("warning: no tokens given: the server is read-only (nobody can push)", file=sys.stderr)
    config = ServerConfig(root=cfg.root, host=cfg.host, port=cfg.port, tokens=cfg.token,
                          token_file=cfg.token_file, orgs=cfg.org, lfs_threshold=cfg.lfs_threshold,
                          public_url=cfg.public_url, limits=cfg.limits())
    server = HubServer(config)
    print(f"msta-hub serving {config.root} at {server.url}", flush=True)
    if cfg.port_file is not None:
        cfg.port_file.write_text(f"{server.port}\n")
    server.serve_forever()
    return 0


def _card(cfg: CardOptions, checkpoint: Path | None = None, eval_policy: str = "",
          ref: str = "") -> CardInfo | None:
    config = None
    if cfg.config_json is not None:
        config = read_json_input(cfg.config_json, "--config_json")
    elif checkpoint is not None and (checkpoint / "config.json").is_file():
        config = read_json_input(checkpoint / "config.json", "config.json")
    if config is not None and not isinstance(config, dict):
        raise ValueError(f"--config_json: expected a JSON object, got {type(config).__name__}")
    figures = EvalFigures()
    if cfg.eval_json is not None:
        figures = read_eval_json(cfg.eval_json, checkpoint, eval_policy, ref)
        if figures.evaluation is not None and checkpoint is None:
            raise EvalJsonError(f"--eval_json {cfg.eval_json}: msta-eval's metrics.json "
                                "describes policies; give it to msta-hub push")
        for line in figures.warnings:
            print(f"msta-hub: warning: {line}", file=sys.stderr)
    fields = (cfg.dataset_repo, cfg.dataset_revision, cfg.stage, cfg.round, cfg.base_model,
              config, figures.table, figures.metrics)
    if all(f is None for f in fields):
        return None
    return CardInfo(dataset_repo=cfg.dataset_repo, dataset_revision=cfg.dataset_revision,
                    config=config, stage=cfg.stage, round=cfg.round, eval_table=figures.table,
                    metrics=figures.metrics, eval_note=figures.note,
                    evaluation=figures.evaluation, base_model=cfg.base_model)


def _push(cfg: PushConfig) -> int:
    assert cfg.checkpoint_dir is not None
    ref = f"{cfg.repo_id}@{cfg.tag}" if cfg.tag else cfg.repo_id
    card = _card(cfg, cfg.checkpoint_dir, cfg.eval_policy, ref)
    sha = push(cfg.checkpoint_dir, cfg.repo_id, tag=cfg.tag, private=cfg.private,
               card=card, branch=cfg.branch, message=cfg.message, move_tag=cfg.move_tag,
               endpoint=cfg.endpoint or None, report=_report)
    print(sha)  # stdout: the commit sha alone, for scripts
    return 0


def _report(pushed: Pushed) -> None:
    """What a push committed and its URL, on stderr (stdout keeps the sha alone)."""
    print(pushed.summary(), file=sys.stderr, flush=True)


def _push_dataset(cfg: PushDatasetConfig) -> int:
    assert cfg.root is not None
    print(push_dataset(cfg.root, cfg.repo_id, private=cfg.private, card=_card(cfg), tag=cfg.tag,
                       message=cfg.message, endpoint=cfg.endpoint or None, report=_report))
    return 0


def _pull(cfg: PullConfig) -> int:
    assert cfg.dest is not None
    print(pull(cfg.spec, cfg.dest, repo_type="dataset" if cfg.dataset else None,
               overwrite=cfg.overwrite, endpoint=cfg.endpoint or None))
    return 0


def _versions(cfg: VersionsConfig) -> int:
    result = versions(cfg.repo_id, repo_type="dataset" if cfg.dataset else "model",
                      with_metrics=not cfg.no_metrics, endpoint=cfg.endpoint or None)
    print(json.dumps(result.to_dict(), indent=2) if cfg.json else result.to_text())
    return 0


@dataclass(frozen=True)
class Command:
    """One ``msta-hub`` command: its config, the bare words it takes, what it does."""

    summary: str
    config: type
    positionals: tuple[str, ...]
    run: Callable


COMMANDS: dict[str, Command] = {
    "serve": Command("run a persistent Hugging Face-compatible hub server", ServeConfig, (),
                     _serve),
    "push": Command("push a checkpoint directory as a new commit of a model repo", PushConfig,
                    ("checkpoint_dir", "repo_id"), _push),
    "push-dataset": Command("push a LeRobot dataset root (tagged with its codebase version)",
                            PushDatasetConfig, ("root", "repo_id"), _push_dataset),
    "pull": Command("download user/name[@revision] into DEST, verified against the hub's "
                    "hashes", PullConfig, ("spec", "dest"), _pull),
    "versions": Command("list tags, branches and commits with the metrics from their cards",
                        VersionsConfig, ("repo_id",), _versions),
}
#: options a command takes as a list, which may also be given once per value (--token A --token B)
_REPEATABLE = ("--token", "--org")


def _overview() -> str:
    width = max(map(len, COMMANDS))
    lines = ["usage: msta-hub [-h] COMMAND [...]   (msta-hub COMMAND --help for its options)",
             "", "run a local hub server, push/pull checkpoints and datasets, list versions",
             "", "commands:"]
    lines += [f"  {name:<{width}}  {c.summary}" for name, c in COMMANDS.items()]
    return "\n".join([*lines, "", _EPILOG])


def _repeated_lists(args: list[str]) -> list[str]:
    """``--token A --token=B`` -> ``--token=["A", "B"]`` (a list given as ``[...]`` stays)."""
    out, values = [], {flag: [] for flag in _REPEATABLE}
    it = iter(args)
    for arg in it:
        flag, sep, value = arg.partition("=")
        flag = "--" + flag[2:].replace("-", "_") if flag.startswith("--") else flag
        if flag in values and not value.startswith("["):
            values[flag].append(value if sep else next(it, ""))
        else:
            out.append(arg)
    return out + [f"{flag}={json.dumps(v)}" for flag, v in values.items() if v]


def parse_command(argv: Sequence[str]) -> tuple[str, object]:
    """``(command, its parsed config)`` from ``argv``; exits 0 after help, 2 on a bad line."""
    args, verbose = list(argv), []
    while args and args[0] in ("-v", "--verbose"):  # msta-hub -v COMMAND ...
        args, verbose = args[1:], ["--verbose=true"]
    if not args or args[0] in ("-h", "--help"):
        if args:
            print(_overview())
            raise SystemExit(0)
        raise usage_error("msta-hub: error: give a command: " + ", ".join(COMMANDS)
                          + "; see msta-hub --help")
    name = args[0]
    rest = ["--verbose=true" if a == "-v" else a for a in args[1:]] + verbose
    if name not in COMMANDS:
        close = difflib.get_close_matches(name, list(COMMANDS), n=1, cutoff=0.5)
        hint = f" (did you mean {close[0]}?)" if close else ""
        raise usage_error(f"msta-hub: error: unknown command {name!r}{hint}; commands: "
                          + ", ".join(COMMANDS))
    command = COMMANDS[name]
    if name == "serve":
        rest = _repeated_lists(rest)
    return name, parse_config(command.config, rest, prog=f"msta-hub {name}",
                              positionals=command.positionals)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``msta-hub``: 0 done, 1 the operation failed, 2 a bad command line."""
    name, cfg = parse_command(list(sys.argv[1:] if argv is None else argv))
    verbose = getattr(cfg, "verbose", False)
    level = logging.INFO if verbose or name == "serve" else logging.WARNING
    logging.basicConfig(level=level, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    if name != "serve" and not verbose:
        logging.getLogger("httpx").setLevel(logging.WARNING)
    try:
        return COMMANDS[name].run(cfg)
    except (HubError, HfHubHTTPError, FileNotFoundError, FileExistsError, ValueError,
            DirectoryLockedError) as err:
        print(f"msta-hub {name}: error: {err}", file=sys.stderr)
        return 1
    except httpx.TransportError as err:  # nothing answers there (refused, no route, timeout)
        url = endpoint_url(getattr(cfg, "endpoint", "") or None)
        print(f"msta-hub {name}: error: cannot reach the hub at {url} ({type(err).__name__}: "
              f"{err}); check --endpoint or HF_ENDPOINT", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
