"""The sensor_faults scenario at run time: the student's actor behind a fault
(:class:`msta.collect.faults.FaultyActor`), the guard hook, and what metrics.json records.

Every round of trials gets a fresh injector seeded by ``(seed, round)`` only, so the
unguarded, oracle and guard runs of a fault, and every fault of the sweep, share the onsets
of the same trials (paired comparisons); the per-step draws (noise, spikes, dropout) are
shared too. The teacher, the reference, runs fault-free.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from msta.collect.faults import FaultInjector, FaultSpec, FaultyActor, std_from_stats
from msta.eval.scenarios import Condition
from msta.policies.actor import StudentActor
from msta.policies.guard_file import load_guard as load

#: Mixed into every injector's seed (apart from the students' mask streams).
FAULT_SEED_TAG = 0xFA17


def fault_seed(seed: int, round_: int) -> list[int]:
    """The injector's seed for round ``round_`` of an evaluation seeded ``seed``."""
    return [int(seed), int(round_), FAULT_SEED_TAG]


def load_guard(path: str, num_envs: int) -> Any:
    """The guard saved with the checkpoint at ``path`` for ``num_envs`` environments, or
    None (no guard saved there)."""
    return load(path, num_envs=num_envs) if path else None


def is_fault_run(cond: Condition) -> bool:
    """Whether ``cond`` changes the student's observation stream or its removal."""
    return cond.fault is not None or cond.removal in ("oracle", "guard")


def fault_key(cond: Condition, seed: int) -> tuple:
    """What the condition adds to the student's inputs key (empty: nothing, so a
    fault-free unguarded run shares its digest with the plain runs)."""
    if not is_fault_run(cond):
        return ()
    fault = str(cond.fault) if cond.fault is not None else "none"
    return (("fault", fault, cond.removal, tuple(fault_seed(seed, 0))),)


def fault_record(cond: Condition, seed: int) -> dict[str, Any]:
    """metrics.json's fields of a sensor_faults run: the fault (spec and its one-string
    form, or None), the removal, and the injector seeds (round r: ``[seed, r, tag]``)."""
    if cond.scenario != "sensor_faults" and not is_fault_run(cond):
        return {}
    return {"fault": cond.fault.as_dict() if cond.fault is not None else None,
            "removal": cond.removal or "unguarded",
            "fault_seed": {"seed": int(seed), "tag": FAULT_SEED_TAG,
                           "per_round": "[seed, round, tag]"}}


def faulty_factory(entry: Any, cond: Condition, seed: int, dt: float,
                   actors: list[FaultyActor] | None = None):
    """(round, n) -> a FaultyActor around the student of ``entry`` (a PolicyEntry) for
    ``cond``; ``actors`` (when given) collects them for :func:`detection_summary`."""
    policy = entry.obj
    std = std_from_stats(policy.processor.stats, policy.required_sensors)

    def make(r: int, n: int) -> FaultyActor:
        student = StudentActor(policy, n, replace(cond.spec, seed=cond.spec.seed * 1_000_003 + r),
                               name=entry.name)
        guard = None
        if cond.removal == "guard":
            guard = load_guard(entry.path, n)
            if guard is None:
                raise NotImplementedError("no guard saved with this checkpoint")
        fault = cond.fault
        if fault is None:  # fault-free: an injector that never turns on
            fault = FaultSpec("stuck", 0, "ang_vel", onset_s=(1e9, 1e9))
        injector = FaultInjector(fault, n, std, dt=dt, seed=fault_seed(seed, r))
        actor = FaultyActor(student, injector, guard=guard, oracle=cond.removal == "oracle")
        if actors is not None:
            actors.append(actor)
        return actor
    return make


def detection_summary(actors: list[FaultyActor], steps_lived: np.ndarray, dt: float,
                      bound_s: float = 0.2) -> dict[str, Any] | None:
    """Detection figures over the trials (each env's first episode, ``steps_lived`` steps):
    the fraction of trials whose fault began that had a fault channel removed, the fraction
    removed within ``bound_s`` of onset, the mean delay (s), and the removed channel-steps
    that were not the active fault's per channel-step. None without actors."""
    if sum(a.num_envs for a in actors) < len(steps_lived):
        return None  # some rounds were read back from the store: no actors to ask
    dets = [a.detections() for a in actors]
    det = {k: np.concatenate([d[k] for d in dets])[:len(steps_lived)]
           for k in ("onset", "detected", "delay")}
    began = det["onset"] < steps_lived
    found = began & (det["detected"] >= 0) & (det["detected"] < steps_lived)
    n = int(began.sum())
    delays = det["delay"][found] * dt
    false, steps = live_false_removals(dets, steps_lived)
    return {"faults_began": n, "detected": float(found.sum() / n) if n else None,
            f"within_{bound_s:g}s": float((delays <= bound_s + 1e-9).sum() / n) if n else None,
            "mean_delay_s": float(delays.mean()) if len(delays) else None,
            "false_alarms_per_channel_step": float(false / steps) if steps else None}


def live_false_removals(dets: list[dict[str, np.ndarray]], steps_lived: np.ndarray
                        ) -> tuple[int, int]:
    """(removed channel-steps that were not the active fault's, channel-steps the guard
    watched) over each trial's live steps only: after a trial's episode ended its robot
    restarts elsewhere (a jump no sensor makes), and those steps count for nothing."""
    false = steps = 0
    start = 0
    for d in dets:
        n = len(d["onset"])
        lived = steps_lived[start:start + n]
        start += n
        by_step = d["false_by_step"]
        if not len(lived) or not len(by_step):
            continue
        live = np.arange(len(by_step))[:, None] < lived[None, :len(by_step[0])]
        false += int((by_step[:, :len(lived)] * live).sum())
        per_step = d["channel_steps"][:len(lived)] / max(len(by_step), 1)
        steps += int(round(float((per_step * np.minimum(lived, len(by_step))).sum())))
    return false, steps
