"""``msta-hub``: run a local hub server, push/pull checkpoints and datasets, list versions.

The client commands talk to HF_ENDPOINT with the token in HF_TOKEN (never on the command
line, so it stays out of shell history and process lists).
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

from huggingface_hub.errors import HfHubHTTPError

from msta_data.errors import DirectoryLockedError
from msta_data.hub_cards import CardInfo
from msta_data.hub_ids import HubError
from msta_data.hub_pull import pull
from msta_data.hub_push import push, push_dataset
from msta_data.hub_versions import versions

_EPILOG = """examples:
  msta-hub serve --root /srv/msta-hub --port 8008 --token-file /etc/msta-hub/tokens
  export HF_ENDPOINT=http://127.0.0.1:8008 HF_TOKEN=...   # then:
  msta-hub push runs/stage1 alice/msta-a1 --tag stage1-r0 --stage 1 --round 0
  msta-hub push-dataset data/a1-teacher alice/a1-teacher
  msta-hub pull alice/msta-a1@stage1-r0 ckpt/stage1
  msta-hub pull datasets/alice/a1-teacher@v3.0 data/a1-teacher
  msta-hub versions alice/msta-a1
"""


def _serve(args: argparse.Namespace) -> int:
    from msta_data.hub_server import HubServer, Limits, ServerConfig

    if not args.token and args.token_file is None:
        print("warning: no tokens given: the server is read-only (nobody can push)", file=sys.stderr)
    limits = Limits(max_body_bytes=args.max_body_bytes, max_commit_bytes=args.max_commit_bytes,
                    read_timeout_s=args.read_timeout, max_card_bytes=args.max_card_bytes,
                    max_connections=args.max_connections)
    config = ServerConfig(root=args.root, host=args.host, port=args.port, tokens=args.token,
                          token_file=args.token_file, orgs=args.org, lfs_threshold=args.lfs_threshold,
                          public_url=args.public_url, limits=limits)
    server = HubServer(config)
    print(f"msta-hub serving {config.root} at {server.url}", flush=True)
    if args.port_file is not None:
        args.port_file.write_text(f"{server.port}\n")
    server.serve_forever()
    return 0


def _card(args: argparse.Namespace, checkpoint: Path | None = None) -> CardInfo | None:
    config = None
    if args.config_json is not None:
        config = json.loads(args.config_json.read_text())
    elif checkpoint is not None and (checkpoint / "config.json").is_file():
        config = json.loads((checkpoint / "config.json").read_text())
    table, metrics = None, None
    if args.eval_json is not None:
        data = json.loads(args.eval_json.read_text())
        if not isinstance(data, dict):
            raise ValueError(f"{args.eval_json}: expected a JSON object of metrics or of table rows")
        if all(isinstance(v, dict) for v in data.values()):
            table = data
        else:
            metrics = {k: v for k, v in data.items() if isinstance(v, (int, float))}
    fields = (args.dataset_repo, args.dataset_revision, args.stage, args.round, config, table, metrics)
    if all(f is None for f in fields):
        return None
    return CardInfo(dataset_repo=args.dataset_repo, dataset_revision=args.dataset_revision, config=config,
                        stage=args.stage, round=args.round, eval_table=table, metrics=metrics)


def _push(args: argparse.Namespace) -> int:
    sha = push(args.checkpoint_dir, args.repo_id, tag=args.tag, private=args.private,
                   card=_card(args, args.checkpoint_dir), branch=args.branch, message=args.message,
                   move_tag=args.move_tag, endpoint=args.endpoint)
    print(sha)
    return 0


def _push_dataset(args: argparse.Namespace) -> int:
    sha = push_dataset(args.root, args.repo_id, private=args.private, card=_card(args), tag=args.tag,
                           message=args.message, endpoint=args.endpoint)
    print(sha)
    return 0


def _pull(args: argparse.Namespace) -> int:
    path = pull(args.spec, args.dest, repo_type="dataset" if args.dataset else None,
                    overwrite=args.overwrite, endpoint=args.endpoint)
    print(path)
    return 0


def _versions(args: argparse.Namespace) -> int:
    result = versions(args.repo_id, repo_type="dataset" if args.dataset else "model",
                          with_metrics=not args.no_metrics, endpoint=args.endpoint)
    print(json.dumps(result.to_dict(), indent=2) if args.json else result.to_text())
    return 0


def _card_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("card (README.md front matter)")
    g.add_argument("--dataset-repo", help="hub id of the training/source dataset")
    g.add_argument("--dataset-revision", help="commit sha or tag of that dataset")
    g.add_argument("--stage", type=int, help="training stage (1 offline, 2 online correction)")
    g.add_argument("--round", type=int, help="correction round")
    g.add_argument("--config-json", type=Path, help="config to record (default: the checkpoint's config.json)")
    g.add_argument("--eval-json", type=Path, help="metrics JSON: {metric: value} or {row: {metric: value}}")


def _limit_arguments(g: argparse._ArgumentGroup) -> None:
    """The request limits of ``msta-hub serve`` (defaults: msta_data.hub_server.Limits)."""
    from msta_data.hub_server.protocol import Limits

    d = Limits()
    g.add_argument("--max-body-bytes", type=int, default=d.max_body_bytes, metavar="BYTES",
                   help=f"largest JSON request body; larger ones get 413 before they are read "
                        f"(default {d.max_body_bytes})")
    g.add_argument("--max-commit-bytes", type=int, default=d.max_commit_bytes, metavar="BYTES",
                   help=f"largest commit body, inline files base64-encoded (default {d.max_commit_bytes}; "
                        "use --lfs-threshold for bigger files)")
    g.add_argument("--read-timeout", type=float, default=d.read_timeout_s, metavar="SECONDS",
                   help=f"drop a client silent this long; a body must also average 1 KiB/s after it "
                        f"(default {d.read_timeout_s:g})")
    g.add_argument("--max-card-bytes", type=int, default=d.max_card_bytes, metavar="BYTES",
                   help=f"largest README.md YAML front matter parsed (default {d.max_card_bytes})")
    g.add_argument("--max-connections", type=int, default=d.max_connections, metavar="N",
                   help=f"connections served at once; more get 503 (default {d.max_connections})")


def build_parser() -> argparse.ArgumentParser:
    """The ``msta-hub`` argument parser."""
    parser = argparse.ArgumentParser(prog="msta-hub", description=__doc__, epilog=_EPILOG,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("-v", "--verbose", action="store_true", help="log requests and progress")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("serve", help="run a persistent Hugging Face-compatible hub server")
    p.add_argument("--root", type=Path, required=True, help="directory holding repos and blobs")
    p.add_argument("--host", default="127.0.0.1", help="interface to bind (default: loopback only)")
    p.add_argument("--port", type=int, default=0, help="TCP port; 0 = pick a free one (printed)")
    p.add_argument("--token", action="append", default=[], metavar="NAME:SECRET",
                   help="a user and its token (repeatable); prefer --token-file")
    p.add_argument("--token-file", type=Path, help="file with one NAME:SECRET per line")
    p.add_argument("--org", action="append", default=[], metavar="ORG:USER1,USER2",
                   help="organisation whose members may write in namespace ORG (repeatable)")
    p.add_argument("--lfs-threshold", type=int, metavar="BYTES",
                   help="upload files >= BYTES through Git LFS (clients need HF_HUB_DISABLE_XET=1)")
    p.add_argument("--public-url", help="base URL for links when behind a proxy")
    p.add_argument("--port-file", type=Path, help="write the bound port to this file")
    _limit_arguments(p.add_argument_group("limits (docs/security.md)"))
    p.set_defaults(func=_serve)

    def client(name: str, help_: str) -> argparse.ArgumentParser:
        c = sub.add_parser(name, help=help_)
        c.add_argument("--endpoint", help="hub URL (default: HF_ENDPOINT)")
        return c

    p = client("push", "push a checkpoint directory as a new commit of a model repo")
    p.add_argument("checkpoint_dir", type=Path)
    p.add_argument("repo_id", help="user/name")
    p.add_argument("--tag", help="tag for this version, e.g. stage1-r0")
    p.add_argument("--move-tag", action="store_true", help="move --tag if it exists on another commit")
    p.add_argument("--branch", default="main")
    p.add_argument("--private", action="store_true", help="create the repo as private")
    p.add_argument("--message", help="commit message")
    _card_options(p)
    p.set_defaults(func=_push)

    p = client("push-dataset", "push a LeRobot dataset root (tagged with its codebase version)")
    p.add_argument("root", type=Path)
    p.add_argument("repo_id", help="user/name")
    p.add_argument("--tag", help="extra tag for this version")
    p.add_argument("--private", action="store_true")
    p.add_argument("--message", help="commit message")
    _card_options(p)
    p.set_defaults(func=_push_dataset)

    p = client("pull", "download user/name[@revision] into DIR, verified against the hub's hashes")
    p.add_argument("spec", help="[datasets/]user/name[@branch|tag|sha]")
    p.add_argument("dest", type=Path)
    p.add_argument("--dataset", action="store_true", help="the repo is a dataset repo")
    p.add_argument("--overwrite", action="store_true", help="replace DEST if it exists")
    p.set_defaults(func=_pull)

    p = client("versions", "list tags, branches and commits with the metrics from their cards")
    p.add_argument("repo_id", help="[datasets/]user/name")
    p.add_argument("--dataset", action="store_true", help="the repo is a dataset repo")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.add_argument("--no-metrics", action="store_true", help="skip reading each commit's card")
    p.set_defaults(func=_versions)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``msta-hub``."""
    args = build_parser().parse_args(argv)
    level = logging.INFO if args.verbose or args.command == "serve" else logging.WARNING
    logging.basicConfig(level=level, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    if args.command != "serve" and not args.verbose:
        logging.getLogger("httpx").setLevel(logging.WARNING)
    try:
        return args.func(args)
    except (HubError, HfHubHTTPError, FileNotFoundError, FileExistsError, ValueError,
            DirectoryLockedError) as err:
        print(f"msta-hub {args.command}: error: {err}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
