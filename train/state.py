"""Training state on disk: optimizer, scheduler, RNG and sampler position as safetensors +
JSON (no pickle anywhere), and run checkpoints written atomically."""

from __future__ import annotations

import json
import os
import random
import shutil
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from msta.policies.base import StudentPolicy
from msta.policies.checkpoint import WEIGHTS_NAME, CheckpointError
from msta.policies.weights import load_weights
from msta.train.sampling import WindowSampler

if TYPE_CHECKING:
    from msta.train.optim import WeightEMA


def atomic_json(path: Path, obj: Any) -> None:
    """Write JSON to ``path`` via a fsync-ed temporary file and a rename."""
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w") as f:
        f.write(json.dumps(obj, indent=2) + "\n")
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def flatten_optimizer_state(state: dict[str, Any]) -> tuple[dict[str, torch.Tensor], dict]:
    """``optimizer.state_dict()`` -> (tensors for safetensors, JSON-ready structure)."""
    tensors: dict[str, torch.Tensor] = {}
    per_param: dict[str, dict[str, Any]] = {}
    for pid, entry in state["state"].items():
        out: dict[str, Any] = {}
        for key, value in entry.items():
            if isinstance(value, torch.Tensor):
                name = f"state.{pid}.{key}"
                tensors[name] = value.detach().cpu().contiguous()
                out[key] = {"__tensor__": name}
            else:
                out[key] = value
        per_param[str(pid)] = out
    return tensors, {"state": per_param, "param_groups": state["param_groups"]}


def unflatten_optimizer_state(tensors: dict[str, torch.Tensor], meta: dict) -> dict[str, Any]:
    """Inverse of :func:`flatten_optimizer_state`."""
    state = {}
    for pid, entry in meta["state"].items():
        state[int(pid)] = {k: tensors[v["__tensor__"]] if isinstance(v, dict) and "__tensor__"
                           in v else v for k, v in entry.items()}
    groups = [{k: tuple(v) if k == "betas" else v for k, v in g.items()}
              for g in meta["param_groups"]]
    return {"state": state, "param_groups": groups}


def rng_state(mask_generator: torch.Generator) -> tuple[dict[str, torch.Tensor], dict]:
    """Every RNG the loop touches: (tensors, JSON)."""
    tensors = {"torch": torch.get_rng_state(), "mask_generator": mask_generator.get_state()}
    if torch.cuda.is_available():
        for i, s in enumerate(torch.cuda.get_rng_state_all()):
            tensors[f"cuda.{i}"] = s
    py = random.getstate()
    np_state = np.random.get_state()
    meta = {"python": [py[0], list(py[1]), py[2]],
            "numpy": [np_state[0], np_state[1].tolist(), *[x for x in np_state[2:]]]}
    return tensors, meta


def set_rng_state(tensors: dict[str, torch.Tensor], meta: dict,
                  mask_generator: torch.Generator) -> None:
    torch.set_rng_state(tensors["torch"])
    mask_generator.set_state(tensors["mask_generator"])
    cuda = [tensors[k] for k in sorted(tensors) if k.startswith("cuda.")]
    if cuda and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(cuda)
    v, s, g = meta["python"]
    random.setstate((v, tuple(s), g))
    name, keys, pos, has_gauss, cached = meta["numpy"]
    np.random.set_state((name, np.asarray(keys, np.uint32), pos, has_gauss, cached))


def save_training_state(directory: Path, step: int, optimizer: torch.optim.Optimizer,
                        scheduler: torch.optim.lr_scheduler.LRScheduler,
                        sampler: WindowSampler, mask_generator: torch.Generator) -> None:
    """Write ``optimizer.safetensors/.json``, ``scheduler.json``, ``rng.safetensors/.json``
    and ``training_step.json`` (step + sampler position) into ``directory``."""
    directory.mkdir(parents=True, exist_ok=True)
    tensors, meta = flatten_optimizer_state(optimizer.state_dict())
    save_file(tensors, str(directory / "optimizer.safetensors"))
    (directory / "optimizer.json").write_text(json.dumps(meta) + "\n")
    (directory / "scheduler.json").write_text(json.dumps(scheduler.state_dict()) + "\n")
    tensors, meta = rng_state(mask_generator)
    save_file(tensors, str(directory / "rng.safetensors"))
    (directory / "rng.json").write_text(json.dumps(meta) + "\n")
    (directory / "training_step.json").write_text(
        json.dumps({"step": step, "sampler": sampler.state_dict()}) + "\n")


def load_training_state(directory: Path, optimizer: torch.optim.Optimizer,
                        scheduler: torch.optim.lr_scheduler.LRScheduler,
                        sampler: WindowSampler, mask_generator: torch.Generator) -> Any:
    """Restore what :func:`save_training_state` wrote; returns the recorded step as stored
    (:func:`check_step` checks it)."""
    missing = [n for n in ("optimizer.safetensors", "optimizer.json", "scheduler.json",
                           "rng.safetensors", "rng.json", "training_step.json")
               if not (directory / n).is_file()]
    if missing:
        raise FileNotFoundError(f"training state {directory} is incomplete: missing {missing}")
    meta = json.loads((directory / "optimizer.json").read_text())
    optimizer.load_state_dict(
        unflatten_optimizer_state(load_file(str(directory / "optimizer.safetensors")), meta))
    scheduler.load_state_dict(json.loads((directory / "scheduler.json").read_text()))
    set_rng_state(load_file(str(directory / "rng.safetensors")),
                  json.loads((directory / "rng.json").read_text()), mask_generator)
    step_info = json.loads((directory / "training_step.json").read_text())
    sampler.load_state_dict(step_info["sampler"])
    return step_info["step"]


def save_checkpoint(out: Path, step: int, policy: StudentPolicy, state: dict[str, Any],
                    ema: WeightEMA | None = None) -> Path:
    """``checkpoints/<step>/`` written under a temporary name, renamed, then ``last`` moved."""
    ckpts = out / "checkpoints"
    final, tmp = ckpts / f"{step:06d}", ckpts / f"{step:06d}.tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    policy.save_pretrained(tmp / "pretrained_model")
    save_training_state(tmp / "training_state", step, **state)
    if ema is not None:
        ema.save(tmp / "training_state")
    shutil.rmtree(final, ignore_errors=True)
    os.replace(tmp, final)
    link = ckpts / "last.tmp"
    link.unlink(missing_ok=True)
    link.symlink_to(final.name)
    os.replace(link, ckpts / "last")
    return final


def last_checkpoint(out: Path) -> Path:
    """``out/checkpoints/last`` resolved: it must be a checkpoint folder of this run (directly
    in ``out/checkpoints``), not a link to another run's, so a resume never continues a
    stranger's training silently.

    Raises:
        CheckpointError: ``last`` leads out of ``out/checkpoints``.
    """
    link = out / "checkpoints" / "last"
    last = link.resolve()
    if last.parent != out.resolve() / "checkpoints":
        raise CheckpointError(f"{link} points to {last}, outside this run's checkpoints "
                              f"({link.parent}); a resume continues only its own run")
    return last


def check_step(step: Any, last: Path, max_step: int) -> int:
    """The step recorded in ``last``'s training state, checked: an integer in
    ``[0, max_step]`` that matches the checkpoint folder's name (``000300``)."""
    where = last / "training_state" / "training_step.json"
    if type(step) is not int or step < 0:
        raise CheckpointError(f"{where}: step {step!r} is not a step count (an integer >= 0)")
    if step > max_step:
        raise CheckpointError(f"{where}: step {step} is beyond --steps={max_step}; give "
                              f"--steps={step} or more to continue this run")
    if last.name.isdigit() and int(last.name) != step:
        raise CheckpointError(f"{where}: step {step} but the checkpoint folder is {last.name}")
    return step


def restore_checkpoint(out: Path, policy: StudentPolicy, state: dict[str, Any],
                       ema: WeightEMA | None = None, max_step: int | None = None) -> int:
    """Load ``checkpoints/last`` into the policy and the loop state; returns its step.

    Args:
        out: the run directory.
        policy: the student (weights loaded in place).
        state: the loop's optimizer, scheduler, sampler and mask generator.
        ema: the weight average, when the run keeps one.
        max_step: the run's total steps: a recorded step beyond it is an error.

    Raises:
        CheckpointError: ``last`` leads out of this run, or the state cannot be restored
            (damaged files, a step that is not an integer in ``[0, max_step]``).
    """
    last = last_checkpoint(out)
    weights = last / "pretrained_model" / WEIGHTS_NAME
    if not weights.is_file():
        raise FileNotFoundError(f"checkpoint {last} has no {weights.name}")
    load_weights(policy, weights)
    if ema is not None:
        ema.load(last / "training_state")
    try:
        step = load_training_state(last / "training_state", **state)
    except (ValueError, KeyError, TypeError, RuntimeError, SafetensorError) as e:
        raise CheckpointError(f"{last / 'training_state'}: cannot restore ({type(e).__name__}: "
                              f"{str(e).splitlines()[0] if str(e) else ''})") from None
    return check_step(step, last, max_step if max_step is not None else step)
