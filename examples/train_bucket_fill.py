"""Train ``bucketfill-ppo``: one bucket-fill policy for WheelLoaderDig-v1 at every scale and soil.

1. Behaviour cloning with DAgger on the tuned scripted cycle (``teacher`` in the config), then the critic is
   fitted to the returns of the cloned policy (:mod:`scaletwin_envs.policies.cloning`).
2. PPO fine-tuning (Stable-Baselines3) on the env's own reward plus a bonus for the fill carried out of the pile
   (:class:`~scaletwin_envs.policies.domain.CompletionBonus`), with a new machine (a preset, or a length ratio
   log-uniform in [0.05, 3] under either scaling law) and soil (all four) every episode
   (:class:`~scaletwin_envs.policies.domain.RandomizedDigEnv`).
   The policy is validated every ``validate_every`` steps on held-out scales and seeds; the best is kept.
3. The result goes to the zoo (safetensors + card, training curves as ``training.rrd``) and is registered.

Everything is seeded from the config; curves are logged to rerun (open the ``.rrd`` with ``rerun FILE``)::

    python examples/train_bucket_fill.py                      # config: examples/bucket_fill_ppo.json
    python examples/train_bucket_fill.py --out /tmp/bf --no-register --ppo-timesteps 4096
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import rerun as rr
import rerun.blueprint as rrb
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.utils import set_random_seed

import scaletwin_envs
import zoo
from scaletwin_envs.envs.wheel_loader_dig import OBS_NAMES
from scaletwin_envs.evaluation import evaluate_policies, machine_info, summarize
from scaletwin_envs.policies import ScriptedDigPolicy
from scaletwin_envs.policies.cloning import collect, fit
from scaletwin_envs.policies.domain import CompletionBonus, RandomizedDigEnv, ScaleSoilSampler
from scaletwin_envs.rollout import run_episode
from zoo.policy import ACTIVATIONS

HERE = Path(__file__).resolve().parent
DEFAULT_CONFIG = HERE / "bucket_fill_ppo.json"


# -- setup ------------------------------------------------------------------------------------------------
def make_env(cfg: dict[str, Any], seed: int) -> gym.Env:
    """The training env: scale and soil randomised per episode, plus the completion bonus."""
    r = cfg["env"]["randomization"]
    sampler = ScaleSoilSampler(tuple(r["scale_range"]), tuple(r["soils"]), tuple(r["laws"]), tuple(r["presets"]),
                               r["preset_probability"])
    return CompletionBonus(RandomizedDigEnv(sampler, cfg["env"]["env_kwargs"], seed=seed),
                           cfg["env"]["completion_bonus"])


def build_model(cfg: dict[str, Any]) -> PPO:
    seed, n_envs = cfg["seed"], cfg["ppo"]["n_envs"]
    vec = make_vec_env(lambda: make_env(cfg, seed), n_envs=n_envs, seed=seed)
    kwargs = {**cfg["policy_kwargs"], "activation_fn": ACTIVATIONS[cfg["policy_kwargs"]["activation_fn"]]}
    ppo = {k: v for k, v in cfg["ppo"].items() if k != "n_envs"}
    return PPO("MlpPolicy", vec, policy_kwargs=kwargs, seed=seed, device="cpu", verbose=0, **ppo)


def teacher_factory(cfg: dict[str, Any]) -> Any:
    params = cfg["teacher"]["params"]
    return lambda: ScriptedDigPolicy(**params)


class Curves:
    """Training curves, buffered per (timeline, entity) and sent to rerun as columns at the end (compact)."""

    def __init__(self) -> None:
        self.series: dict[tuple[str, str], list[tuple[int, float]]] = {}

    def add(self, timeline: str, step: int, path: str, value: float) -> None:
        if np.isfinite(value):
            self.series.setdefault((timeline, path), []).append((int(step), float(value)))

    def save(self, path: Path) -> None:
        """Write every curve to an ``.rrd`` with one time-series view per group (bc, ppo, validation)."""
        rec = rr.RecordingStream("scaletwin_bucketfill")
        groups = sorted({p.split("/")[0] for _, p in self.series})
        views = [rrb.TimeSeriesView(origin=f"/{g}", name=g) for g in groups]
        rec.save(str(path), default_blueprint=rrb.Blueprint(rrb.Tabs(*views)))
        for (timeline, entity), points in self.series.items():
            steps, values = zip(*points, strict=True)
            rec.send_columns(entity, indexes=[rr.TimeColumn(timeline, sequence=steps)],
                             columns=rr.Scalars.columns(scalars=values))
        rec.flush()
        rec.disconnect()


# -- behaviour cloning ------------------------------------------------------------------------------------
def warm_start(model: PPO, cfg: dict[str, Any], curves: Curves) -> dict[str, Any]:
    """DAgger rounds on the teacher, then the critic on the cloned policy's returns."""
    bc, gamma = cfg["behaviour_cloning"], cfg["ppo"]["gamma"]
    env, teacher, policy = make_env(cfg, cfg["seed"] + 10_000), teacher_factory(cfg), model.policy
    env.reset(seed=cfg["seed"] + 10_000)
    data = collect(env, teacher, bc["teacher_episodes"], gamma=gamma)
    epoch, stats = 0, {"teacher_fill": float(data.fills.mean()), "student_fill": []}
    for rnd in range(bc["dagger_rounds"] + 1):
        if rnd:
            new = collect(env, teacher, bc["dagger_episodes"], student=policy, gamma=gamma)
            stats["student_fill"].append(float(new.fills.mean()))
            curves.add("dagger_round", rnd, "bc/student_fill", new.fills.mean())
            data = data.concat(new)
        epochs = bc["first_epochs"] if rnd == 0 else bc["round_epochs"]
        losses = fit(policy, data, "actor", epochs, bc["batch_size"], bc["learning_rate"], seed=cfg["seed"] + rnd)
        for loss in losses:
            epoch += 1
            curves.add("bc_epoch", epoch, "bc/actor_loss", loss)
        print(f"[bc] round {rnd}: {len(data)} transitions, actor loss {losses[-1]:.4f}", flush=True)
    on_policy = collect(env, teacher, bc["dagger_episodes"], student=policy, gamma=gamma)
    for i, loss in enumerate(fit(policy, on_policy, "critic", bc["critic_epochs"], bc["batch_size"],
                                 bc["learning_rate"], seed=cfg["seed"])):
        curves.add("critic_epoch", i + 1, "bc/critic_loss", loss)
    stats.update(transitions=len(data), critic_transitions=len(on_policy))
    return stats


# -- validation and PPO -----------------------------------------------------------------------------------
def validate(policy: Any, cfg: dict[str, Any]) -> dict[str, float]:
    """Deterministic episodes on the held-out validation cells: mean training return (the selection score),
    fills and the fraction of completed cycles."""
    v, returns, fills, completed = cfg["validation"], [], [], []
    for scale in v["scales"]:
        for soil in v["soils"]:
            env = CompletionBonus(gym.make(scaletwin_envs.ENV_ID, scale=scale, soil=soil, **cfg["env"]["env_kwargs"]),
                                  cfg["env"]["completion_bonus"])
            for i in range(v["episodes"]):
                ep = run_episode(env, policy, seed=v["seed"] + i)
                returns.append(sum(sum(info["reward_terms"].values()) for info in ep.infos))
                fills.append((soil, ep.kpis.fill_factor))
                completed.append("completion" in ep.infos[-1]["reward_terms"])
            env.close()
    gravel = [f for s, f in fills if s == "gravel"] or [f for _, f in fills]
    return {"score": float(np.mean(returns)), "mean_fill": float(np.mean([f for _, f in fills])),
            "gravel_min_fill": float(np.min(gravel)), "completed": float(np.mean(completed))}


class TrainingLog(BaseCallback):
    """Logs PPO's episodes and losses to rerun, validates periodically and keeps the best policy weights."""

    def __init__(self, cfg: dict[str, Any], curves: Curves, start: dict[str, float]) -> None:
        super().__init__()
        self.cfg, self.curves = cfg, curves
        self.every = cfg["budget"]["validate_every"]
        self.best = dict(start)
        self.best_state: dict[str, torch.Tensor] | None = None
        self.best_step, self.next_check, self.history = 0, self.every, [{"timesteps": 0, **start}]
        self.episodes: list[tuple[float, float, int]] = []
        self.t0 = time.perf_counter()

    def _on_training_start(self) -> None:
        self.best_state = copy.deepcopy(self.model.policy.state_dict())

    def _on_step(self) -> bool:
        for done, info in zip(self.locals["dones"], self.locals["infos"], strict=True):
            if done and "episode" in info:
                self.episodes.append((info["episode"]["r"], info.get("fill_factor", 0.0), info["episode"]["l"]))
        return True

    def _on_rollout_start(self) -> None:
        for key in ("approx_kl", "clip_fraction", "value_loss", "policy_gradient_loss", "std", "explained_variance"):
            value = self.model.logger.name_to_value.get(f"train/{key}")
            if value is not None:
                self.curves.add("timesteps", self.num_timesteps, f"ppo/train/{key}", value)

    def _on_rollout_end(self) -> None:
        if self.episodes:
            r, f, n = (np.mean(x) for x in zip(*self.episodes, strict=True))
            for path, value in (("ppo/episode_return", r), ("ppo/episode_fill", f), ("ppo/episode_length", n)):
                self.curves.add("timesteps", self.num_timesteps, path, value)
            print(f"[ppo] {self.num_timesteps:>7d} steps: return {r:.3f}, fill {f:.3f}, "
                  f"{self.num_timesteps / (time.perf_counter() - self.t0):.0f} steps/s", flush=True)
            self.episodes = []
        if self.num_timesteps >= self.next_check:
            self.next_check += self.every
            self.validate_now()

    def validate_now(self) -> None:
        result = validate(self.model.policy, self.cfg)
        self.history.append({"timesteps": self.num_timesteps, **result})
        for key, value in result.items():
            self.curves.add("timesteps", self.num_timesteps, f"validation/{key}", value)
        if result["score"] > self.best["score"]:
            self.best, self.best_step = result, self.num_timesteps
            self.best_state = copy.deepcopy(self.model.policy.state_dict())
        print(f"[val] {self.num_timesteps} steps: {result} (best at {self.best_step})", flush=True)


def fine_tune(model: PPO, cfg: dict[str, Any], curves: Curves) -> dict[str, Any]:
    """PPO on the randomised env; the best validated weights end up in ``model.policy``."""
    start = validate(model.policy, cfg)
    print(f"[val] 0 steps (cloned): {start}", flush=True)
    for key, value in start.items():
        curves.add("timesteps", 0, f"validation/{key}", value)
    log = TrainingLog(cfg, curves, start)
    model.learn(total_timesteps=cfg["budget"]["ppo_timesteps"], callback=log, progress_bar=False)
    if log.history[-1]["timesteps"] != model.num_timesteps:
        log.validate_now()
    model.policy.load_state_dict(log.best_state)
    return {"timesteps": int(model.num_timesteps), "best_timesteps": log.best_step, "validation_start": start,
            "validation_best": log.best, "validation_history": log.history}


# -- card and main ----------------------------------------------------------------------------------------
def kpi_metrics(policy: Any, cfg: dict[str, Any]) -> dict[str, Any]:
    """Deterministic KPIs on the evaluation cells (the benchmark seeds), per scale and soil."""
    e = cfg["evaluation"]
    summary = summarize(evaluate_policies({"learned": policy}, e["scales"], e["soils"], e["episodes"], e["seed"],
                                          env_kwargs=cfg["env"]["env_kwargs"], executor="serial"))
    cols = ["fill_factor", "cycle_time_froude", "specific_energy", "success_rate", "sim_errors"]
    return {"protocol": {**e, "deterministic": True},
            "per_cell": {f"{r.scale}/{r.soil}": {c: float(getattr(r, c)) for c in cols} for r in summary.itertuples()}}


def card_fields(cfg: dict[str, Any], config_text: str, stats: dict[str, Any]) -> dict[str, Any]:
    return {
        "name": cfg["name"], "description": cfg["description"], "env_id": cfg["env"]["id"],
        "env_kwargs": cfg["env"]["env_kwargs"], "seed": cfg["seed"], "observation_names": list(OBS_NAMES),
        "action_names": ["lift", "tilt", "drive"],
        "training": {"method": "behaviour cloning (DAgger) on the tuned scripted cycle, then PPO fine-tuning",
                     "randomization": cfg["env"]["randomization"], "teacher": cfg["teacher"],
                     "config": json.loads(config_text), "script": "examples/train_bucket_fill.py",
                     "machine": machine_info(), **stats},
    }


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--config", type=Path, default=DEFAULT_CONFIG)
    p.add_argument("--out", type=Path, help="checkpoint directory (default: zoo/checkpoints/<name>)")
    p.add_argument("--no-register", action="store_true", help="do not add the checkpoint to zoo/registry.json")
    p.add_argument("--ppo-timesteps", type=int, help="override the PPO budget (e.g. for a smoke run)")
    return p.parse_args(argv)


def train(cfg: dict[str, Any], curves: Curves) -> tuple[PPO, dict[str, Any]]:
    """Behaviour cloning, then PPO; the model and the statistics for the card (with wall times)."""
    torch.set_num_threads(cfg["torch_threads"])
    set_random_seed(cfg["seed"])
    model, times = build_model(cfg), {}
    t = time.perf_counter()
    stats = {"behaviour_cloning": warm_start(model, cfg, curves)}
    times["behaviour_cloning_s"] = time.perf_counter() - t
    t = time.perf_counter()
    stats["ppo"] = fine_tune(model, cfg, curves)
    times["ppo_s"] = time.perf_counter() - t
    stats["wall_time"] = {**{k: round(v, 1) for k, v in times.items()}, "total_s": round(sum(times.values()), 1)}
    print(f"[done] wall time {stats['wall_time']}", flush=True)
    return model, stats


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    config_text = args.config.read_text()
    cfg = json.loads(config_text)
    if args.ppo_timesteps is not None:
        cfg["budget"]["ppo_timesteps"] = args.ppo_timesteps
    out = args.out or zoo.ZOO_ROOT / "checkpoints" / cfg["name"]
    curves = Curves()
    model, stats = train(cfg, curves)
    fields = {**card_fields(cfg, config_text, stats), "metrics": kpi_metrics(model.policy, cfg)}
    with tempfile.TemporaryDirectory() as tmp:
        rrd = Path(tmp) / "training.rrd"
        curves.save(rrd)
        zoo.save_policy(model, out, fields, attachments={"training.rrd": rrd}, overwrite=True)
    if not args.no_register:
        zoo.register(cfg["name"], out)
    print(f"[done] saved {out}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
