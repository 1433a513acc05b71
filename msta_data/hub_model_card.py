"""Model cards (README.md of a checkpoint repo) in Hugging Face's conventions.

The front matter is what a Hugging Face user and the hub expect of a robotics checkpoint:
``library_name`` (``lerobot`` for a checkpoint in LeRobot's layout, as lerobot-train writes
it; ``msta`` for msta's own), ``pipeline_tag: robotics``, ``tags``, ``license``, ``datasets``
and ``base_model`` where known, and ``model-index`` holding the figures (rounded to four
significant digits, 95 % intervals in each metric's ``args``); msta's own block (``msta``)
keeps every number and the training configuration, without LeRobot's run settings.

The body's usage snippet is for the checkpoint's layout: an msta checkpoint loads with
msta and converts for lerobot-eval; a LeRobot one is pulled and given to lerobot-eval as it
is. Every value a user or a file chose (tag, names, dataset, notes) is written through
:mod:`msta.data.hub_markdown`, so it renders as the text it is.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from huggingface_hub import EvalResult, ModelCardData

from msta.data import hub_markdown as md
from msta.data.hub_cards import (
    LICENSE,
    STAGES,
    CardInfo,
    bounds_key,
    evaluation_section,
    front_matter,
    portable,
)
from msta.data.hub_eval import CardInputError, read_json_input
from msta.data.hub_ids import is_hub_id, parse_hub_id

#: LeRobot's saved preprocessor: its presence makes a checkpoint LeRobot's layout (the name
#: ``msta.policies.checkpoint.LEROBOT_PREPROCESSOR`` gives it; msta.data may not import it).
LEROBOT_PREPROCESSOR = "policy_preprocessor.json"
#: The run configuration lerobot-train and msta-train save beside the weights.
TRAIN_CONFIG = "train_config.json"
#: Fields of LeRobot's ``PreTrainedConfig`` that say where a run ran and how it was to be
#: pushed, not what the model is: never copied into a card.
LEROBOT_RUNTIME_FIELDS = ("device", "use_amp", "use_peft", "push_to_hub", "repo_id", "private",
                          "tags", "license", "pretrained_path", "pretrained_revision")
#: Figures that count rather than measure: on the card, not in ``model-index``.
COUNT_FIGURES = ("trials", "eval_trials", "step", "episodes")
#: A checkpoint's small JSON files read for its card (config.json, train_config.json).
MAX_CHECKPOINT_JSON_BYTES = 4 << 20


@dataclass(frozen=True)
class CheckpointFacts:
    """What a checkpoint directory says about itself, for its card and commit.

    Args:
        layout: "lerobot" (LeRobot's files, e.g. lerobot-train's ``pretrained_model``) or
            "msta".
        policy_type: ``config.json``'s ``type`` (None when it has none).
        dataset: hub id of the training dataset its run configuration names (None: unknown
            or a local folder).
        base_model: hub id of the checkpoint training started from (None: unknown or local).
        name: how a commit title names it (``last/pretrained_model`` for lerobot-train's).
    """

    layout: str = "msta"
    policy_type: str | None = None
    dataset: str | None = None
    base_model: str | None = None
    name: str = ""


def _json(path: Path) -> dict[str, Any]:
    """A checkpoint's JSON object ({} when missing, unreadable or not an object)."""
    try:
        data = read_json_input(path, path.name, MAX_CHECKPOINT_JSON_BYTES)
    except CardInputError:
        return {}
    return data if isinstance(data, dict) else {}


def _hub_ref(value: Any) -> str | None:
    """``value`` when it is a hub id (not a local path), else None."""
    return value if isinstance(value, str) and value and is_hub_id(value) else None


def started_from(config: dict[str, Any] | None) -> str | None:
    """The hub id of the checkpoint a run configuration trained from (LeRobot's
    ``policy.pretrained_path``, msta's ``policy.path``: msta-correct, msta-finetune), or
    None (a new policy, or a local checkpoint)."""
    policy = (config or {}).get("policy")
    if not isinstance(policy, dict):
        return None
    return _hub_ref(policy.get("pretrained_path")) or _hub_ref(policy.get("path"))


def checkpoint_facts(root: str | os.PathLike) -> CheckpointFacts:
    """:class:`CheckpointFacts` of checkpoint directory ``root``: its layout, type, and from
    its run configuration (``train_config.json``: LeRobot's ``dataset.repo_id``, msta's
    ``dataset``; :func:`started_from`) the dataset and the checkpoint it was trained from,
    when those are hub ids."""
    root = Path(root)
    layout = "lerobot" if (root / LEROBOT_PREPROCESSOR).is_file() else "msta"
    kind = _json(root / "config.json").get("type")
    train = _json(root / TRAIN_CONFIG)
    dataset = train.get("dataset")
    if isinstance(dataset, dict):  # lerobot-train's DatasetConfig
        dataset = dataset.get("repo_id")
    dataset = _hub_ref(dataset)
    name = f"{root.parent.name}/{root.name}" if root.name == "pretrained_model" else root.name
    return CheckpointFacts(layout, kind if isinstance(kind, str) else None,
                           parse_hub_id(dataset, "dataset").repo_id if dataset else None,
                           started_from(train), name)


def card_config(config: dict[str, Any] | None, layout: str) -> dict[str, Any] | None:
    """The configuration a card records: without local paths (:func:`portable`) and, for a
    LeRobot checkpoint, without LeRobot's run settings (:data:`LEROBOT_RUNTIME_FIELDS`)."""
    if config is None:
        return None
    drop = LEROBOT_RUNTIME_FIELDS if layout == "lerobot" else ()
    return portable({k: v for k, v in config.items() if k not in drop})


# ----- front matter ----------------------------------------------------------------------
def rounded(value: float) -> float | int:
    """A figure as the card's ``model-index`` shows it: counts whole, other numbers to four
    significant digits (0.6, not 0.6000000000000001)."""
    if isinstance(value, int) and not isinstance(value, bool):
        return value
    return float(f"{float(value):.4g}")


def _figures(info: CardInfo) -> list[tuple[str, float, tuple[float, float] | None]]:
    """(name, value, 95 % bounds) of every flat metric and eval-table cell (``row/column``),
    counts left out."""
    rows = [("", info.metrics or {})]
    rows += [(f"{row}/", cols) for row, cols in (info.eval_table or {}).items()]
    out = []
    for prefix, row in rows:
        for key, value in row.items():
            if "_ci95_" in key or key.partition("@")[0] in COUNT_FIGURES \
                    or not isinstance(value, (int, float)) or isinstance(value, bool):
                continue
            low, high = row.get(bounds_key(key, "low")), row.get(bounds_key(key, "high"))
            ok = all(isinstance(b, (int, float)) for b in (low, high))
            out.append((prefix + key, value, (low, high) if ok else None))
    return out


def eval_results(info: CardInfo) -> list[EvalResult]:
    """The card's figures as huggingface_hub's ``EvalResult`` (``model-index``): losses on
    the training dataset, the other figures on msta-eval's trials in simulation."""
    out = []
    for name, value, ci in _figures(info):
        training = "loss" in name or "mse" in name
        dataset = (portable(info.dataset_repo) if training and info.dataset_repo
                   else "training data" if training else "msta-eval")
        label = name if ci is None else (f"{name} (95 % interval {rounded(ci[0])} to "
                                         f"{rounded(ci[1])})")
        args = None if ci is None else {"ci95_low": rounded(ci[0]), "ci95_high": rounded(ci[1])}
        out.append(EvalResult(
            task_type="robotics", task_name="quadruped locomotion", dataset_type=dataset,
            dataset_name=dataset if training else "simulated trials (msta-eval)",
            dataset_revision=info.dataset_revision if training and info.dataset_repo else None,
            metric_type=name, metric_value=rounded(value), metric_name=label,
            metric_args=args))
    return out


def base_model(info: CardInfo, facts: CheckpointFacts) -> str | None:
    """The checkpoint this one was trained from: ``info.base_model``, else what the card's
    configuration (msta-correct's ``policy.path``) or the checkpoint's run configuration
    names, when it is a hub id."""
    return info.base_model or started_from(info.config) or facts.base_model


def model_front_matter(info: CardInfo, repo_id: str, facts: CheckpointFacts) -> dict[str, Any]:
    """The front matter of a model card (module docstring)."""
    lerobot = facts.layout == "lerobot"
    tags = ["lerobot", "robotics", "msta", "quadruped"] if lerobot else \
        ["msta", "robotics", "quadruped", "lerobot"]
    if facts.policy_type and facts.policy_type not in tags:
        tags.append(facts.policy_type)
    dataset = info.dataset_repo or facts.dataset
    base = base_model(info, facts)
    results = eval_results(info)
    data = ModelCardData(
        library_name="lerobot" if lerobot else "msta", pipeline_tag="robotics", tags=tags,
        license=LICENSE, datasets=[portable(dataset)] if dataset else None,
        base_model=parse_hub_id(base).repo_id if base and is_hub_id(base) else None,
        model_name=repo_id or "msta checkpoint", eval_results=results or None)
    meta = data.to_dict()
    meta["msta"] = info.msta_metadata()
    if base:
        meta["msta"]["base_model"] = portable(base)
    if "config" in meta["msta"]:
        meta["msta"]["config"] = card_config(info.config, facts.layout)
    return meta


# ----- body ------------------------------------------------------------------------------
#: lerobot-eval's options on the card (msta's simulator, the evaluation's size, no videos).
LEROBOT_EVAL_OPTIONS = ("--env.type=msta_a1", "--eval.n_episodes=10", "--eval.batch_size=10",
                        "--env.video=false", "--eval.recording=true")


def lerobot_eval_command(folder: str) -> str:
    """The lerobot-eval line of a card, evaluating the LeRobot checkpoint in ``folder``."""
    return " ".join(["lerobot-eval", LEROBOT_EVAL_OPTIONS[0], f"--policy.path={md.shell(folder)}",
                     *LEROBOT_EVAL_OPTIONS[1:]])


def _usage(ref: str, facts: CheckpointFacts) -> list[str]:
    repo, _, tag = ref.partition("@")
    kind = facts.policy_type or "msta"
    folder = repo.rsplit("/", 1)[-1] or "checkpoint"
    lines = ["## Usage", ""]
    if kind == "msta" or facts.layout == "msta":  # msta's loaders read both layouts of msta
        rev = f", revision={md.python_str(tag)}" if tag else ""
        lines += ["```python", "from msta.policies.factory import get_policy_class, load_policy",
                  "", f"policy = load_policy({md.python_str(ref)})  # or a local checkpoint "
                  "directory", f"policy = get_policy_class({md.python_str(kind)})"
                  f".from_pretrained({md.python_str(repo)}{rev})  # the same",
                  "actions = policy.act(batch)  # batch: sensor windows, see docs/msta_model.md",
                  "```", ""]
    lines += ["```bash"]
    if facts.layout == "lerobot":  # LeRobot's files: lerobot-eval takes the pulled folder
        lines += [f"msta-hub pull {md.shell(ref)} {md.shell(folder)}"]
        if kind == "msta":
            lines += [lerobot_eval_command(folder),
                      f"msta-eval --policies {md.shell('teacher,' + ref)} --suite quick"]
    else:
        lines += [f"msta-eval --policies {md.shell('teacher,' + ref)} --suite quick"]
        if kind == "msta":  # LeRobot's layout through the converter (msta students only)
            lines += [f"python -m lerobot_policy_msta.convert --policy.path={md.shell(ref)} "
                      "--output_dir=msta_lerobot", lerobot_eval_command("msta_lerobot")]
    return [*lines, "```", ""]


def _training(info: CardInfo, facts: CheckpointFacts) -> list[str]:
    lines = []
    dataset, base = info.dataset_repo or facts.dataset, base_model(info, facts)
    if dataset:
        rev = (f" at revision {md.code(info.dataset_revision)}" if info.dataset_revision
               else " (a local dataset: no hub revision)" if info.dataset_repo else "")
        lines.append(f"- **Training data**: dataset {md.code(portable(dataset))}{rev}")
    if base:
        lines.append(f"- **Fine-tuned from**: {md.code(portable(base))}")
    if info.stage is not None:
        what = STAGES.get(info.stage) if isinstance(info.stage, int) else None
        rnd = f", round {md.text(info.round)}" if info.round is not None else ""
        lines.append(f"- **Stage**: {md.text(info.stage)}{rnd}" + (f" ({what})" if what else ""))
    if info.config is not None:
        lines.append("- **Configuration**: `msta.config` in this card's front matter")
    if not lines and not info.notes:
        return []
    return ["## Training", "", *lines, "", *([info.notes, ""] if info.notes else [])]


def model_card(info: CardInfo, repo_id: str = "", revision: str | None = None,
               facts: CheckpointFacts | None = None) -> str:
    """README.md text (YAML front matter + Markdown) for a checkpoint: a usage snippet for
    its layout, what it was trained on (dataset and revision, base model, stage and round),
    its figures (the eval table with its trial count) and the license; local paths are
    never written.

    Args:
        info: what to record.
        repo_id: used in the default title, ``model-index`` and the usage snippet.
        revision: the tag the checkpoint is pushed with (in the usage snippet).
        facts: the checkpoint's layout, type, dataset and base model
            (:func:`checkpoint_facts`); default: an msta checkpoint of type ``msta``.
    """
    facts = facts or CheckpointFacts()
    ref = f"{repo_id}@{revision}" if repo_id and revision else repo_id or "<user/name@tag>"
    what = "LeRobot checkpoint" if facts.layout == "lerobot" else "checkpoint"
    title = md.text(info.title or f"MSTA {what} {repo_id}".strip())
    body = [f"# {title}", "", *_usage(ref, facts), *_training(info, facts),
            *evaluation_section(info), "## License", "", f"`{LICENSE}` (Apache License 2.0)."]
    meta = model_front_matter(info, repo_id, facts)
    return front_matter(meta) + "\n".join(body).rstrip() + "\n"
