"""Dataset sweeps: scales × soils × pile variations × seeds, one Parquet recording per episode.

Each episode is an :class:`EpisodeTask`, named by a stable hash of its parameters (``ep-<hash>.parquet``).
Episodes run through the executor seam (:func:`scaletwin_envs.parallel.make_executor`: local processes by
default); each worker writes its own file atomically, so an interrupted sweep loses no finished episode and
leaves no partial file, and a rerun skips every episode whose file exists. ``manifest.json`` lists the sweep,
the versions and every episode's parameters and status.
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib
import itertools
import json
import time
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import pandas as pd
from tqdm.auto import tqdm

import scaletwin_envs
from scaletwin_envs.parallel import Executor, make_executor
from scaletwin_envs.policies import ScriptedDigPolicy
from scaletwin_envs.recording.atomic import write_text_atomic
from scaletwin_envs.recording.recorder import record_episode
from scaletwin_envs.recording.recording import read_recording
from scaletwin_envs.recording.schema import SCHEMA_VERSION
from scaletwin_envs.specs.loader import LoaderSpec

MANIFEST = "manifest.json"
SERIAL_MAX = 8  # sweeps with at most this many episodes to run go serially when no executor is given
MANIFEST_INTERVAL = 2.0  # s between manifest rewrites while a sweep runs (and once at the end)
PolicyFactory = Callable[..., Any]


def make_policy(policy: str, **kwargs: Any) -> Any:
    """``"scripted"`` (:class:`ScriptedDigPolicy`) or a factory ``"package.module:function"`` called with kwargs."""
    if policy == "scripted":
        return ScriptedDigPolicy(**kwargs)
    module, sep, attr = policy.partition(":")
    if not sep or not module or not attr:
        raise ValueError(f"policy must be 'scripted' or an import string 'module:function', got {policy!r}")
    factory = importlib.import_module(module)
    for part in attr.split("."):
        factory = getattr(factory, part)
    return factory(**kwargs)


def policy_name(policy: str | PolicyFactory) -> str:
    """The import string of a policy factory (a module-level function, so worker processes can import it)."""
    if isinstance(policy, str):
        return policy
    name = f"{policy.__module__}:{policy.__qualname__}"
    if "<" in name:
        raise ValueError(f"policy factory {name} is not importable; use a module-level function")
    return name


@dataclass(frozen=True)
class EpisodeTask:
    """One episode of a sweep (picklable; all fields JSON values)."""

    scale: float | str | dict[str, Any]
    soil: str
    pile_distance: float
    pile_height: float
    seed: int
    policy: str = "scripted"
    law: str = "product_line"
    policy_kwargs: dict[str, Any] = field(default_factory=dict)
    env_kwargs: dict[str, Any] = field(default_factory=dict)

    def params(self) -> dict[str, Any]:
        return asdict(self)

    def machine(self) -> float | str | LoaderSpec:
        """The ``scale`` argument of the env: a preset, a length ratio, or a :class:`LoaderSpec` given as its
        dictionary (:meth:`LoaderSpec.to_dict`, e.g. a machine of the product-line design space)."""
        return LoaderSpec.from_dict(self.scale) if isinstance(self.scale, Mapping) else self.scale

    def key(self) -> str:
        """Stable hash of the parameters and the recording schema version (16 hex digits)."""
        text = json.dumps({**self.params(), "schema_version": SCHEMA_VERSION}, sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    @property
    def filename(self) -> str:
        return f"ep-{self.key()}.parquet"


@dataclass(frozen=True)
class SweepSpec:
    """The grid of a dataset sweep (lengths in boom lengths, as the env's ``pile_distance``/``pile_height``).

    Args:
        scales: presets or length ratios vs the ER12.  soils: soil names.
        pile_distances, pile_heights: pile variations.  seeds: reset seeds.
        policy: ``"scripted"``, a factory import string ``"module:function"``, or a module-level factory.
        policy_kwargs: passed to the factory.  law: scaling law of float scales.
        env_kwargs: further env arguments (JSON values), the same for every episode.
    """

    scales: tuple[float | str, ...] = ("mini",)
    soils: tuple[str, ...] = ("gravel",)
    pile_distances: tuple[float, ...] = (0.5,)
    pile_heights: tuple[float, ...] = (0.7,)
    seeds: tuple[int, ...] = (0,)
    policy: str | PolicyFactory = "scripted"
    policy_kwargs: Mapping[str, Any] = field(default_factory=dict)
    law: str = "product_line"
    env_kwargs: Mapping[str, Any] = field(default_factory=dict)

    def tasks(self) -> list[EpisodeTask]:
        """Every combination, in a stable order (seeds vary fastest); duplicates removed."""
        name = policy_name(self.policy)
        grid = itertools.product(self.scales, self.soils, self.pile_distances, self.pile_heights, self.seeds)
        tasks = {}
        for scale, soil, dist, height, seed in grid:
            t = EpisodeTask(scale, soil, float(dist), float(height), int(seed), name, self.law,
                            dict(self.policy_kwargs), dict(self.env_kwargs))
            tasks.setdefault(t.key(), t)
        return list(tasks.values())

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["policy"] = policy_name(self.policy)
        return d


def run_task(job: tuple[EpisodeTask, str]) -> dict[str, Any]:
    """Record one episode into ``<out_dir>/<task.filename>`` (atomic); returns its summary.

    Errors are returned (``status="failed"``), not raised, so one bad episode does not stop a sweep.
    """
    task, out_dir = job
    path = Path(out_dir) / task.filename
    summary: dict[str, Any] = {"key": task.key(), "file": task.filename}
    if path.exists():
        return {**summary, "status": "done"}
    start = time.perf_counter()
    try:
        env = gym.make(scaletwin_envs.ENV_ID, scale=task.machine(), law=task.law, soil=task.soil,
                       pile_distance=task.pile_distance, pile_height=task.pile_height, **task.env_kwargs)
        try:
            rec = record_episode(env, make_policy(task.policy, **task.policy_kwargs), task.seed)
        finally:
            env.close()
        extra = {**rec.provenance.extra, "sweep_task": {**task.params(), "key": task.key()}}
        rec.provenance = dataclasses.replace(rec.provenance, extra=extra)
        rec.to_parquet(path)
    except Exception as exc:  # reported in the manifest; the file is absent, so a rerun retries it
        return {**summary, "status": "failed", "error": f"{type(exc).__name__}: {exc}"}
    last = rec.data.iloc[-1] if len(rec) else {}
    return {**summary, "status": "done", "steps": len(rec), "seconds": time.perf_counter() - start,
            "fill_factor": float(last.get("fill_factor", float("nan"))),
            "sim_error": rec.provenance.extra.get("sim_error")}


@dataclass
class SweepResult:
    """What a sweep did: episodes run now, skipped (already on disk) and failed, and the manifest."""

    out_dir: Path
    ran: int
    skipped: int
    failed: int
    seconds: float
    manifest: dict[str, Any]


def run_sweep(spec: SweepSpec, out_dir: str | Path, executor: str | int | Executor | None = None,
              progress: bool = True) -> SweepResult:
    """Run every episode of ``spec`` whose file is not in ``out_dir`` yet.

    Args:
        spec: the grid.  out_dir: dataset folder (created).
        executor: see :func:`make_executor` (None: local processes on all cores, or serial for at most
            :data:`SERIAL_MAX` episodes, where process start-up would cost more than it saves).
        progress: show a tqdm bar.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    tasks = spec.tasks()
    manifest = _new_manifest(spec, tasks, out)
    todo = [t for t in tasks if manifest["episodes"][t.key()]["status"] != "done"]
    skipped, failed, start = len(tasks) - len(todo), 0, time.perf_counter()
    _write_manifest(out, manifest)
    bar = tqdm(total=len(tasks), initial=skipped, desc="episodes", unit="ep", disable=not progress)
    written = time.monotonic()
    try:
        if executor is None and len(todo) <= SERIAL_MAX:
            executor = "serial"  # starting processes costs seconds, more than a few episodes
        for _, summary in make_executor(executor).map_unordered(run_task, [(t, str(out)) for t in todo]):
            manifest["episodes"][summary["key"]].update(summary)
            failed += summary["status"] == "failed"
            bar.update(1)
            if time.monotonic() - written >= MANIFEST_INTERVAL:  # the files are the truth; this is the summary
                _write_manifest(out, manifest)
                written = time.monotonic()
    finally:
        bar.close()
        _write_manifest(out, manifest)
    return SweepResult(out, len(todo), skipped, failed, time.perf_counter() - start, manifest)


def _new_manifest(spec: SweepSpec, tasks: list[EpisodeTask], out: Path) -> dict[str, Any]:
    old = _read_manifest(out).get("episodes", {})
    episodes = {}
    for t in tasks:
        entry = {**t.params(), "file": t.filename, "status": "pending"}
        if (out / t.filename).exists():
            entry = {**entry, **old.get(t.key(), {}), "status": "done"}
        episodes[t.key()] = entry
    return {"format": "scaletwin.dataset", "schema_version": SCHEMA_VERSION,
            "package_version": scaletwin_envs.__version__, "spec": spec.to_dict(), "episodes": episodes}


def _read_manifest(out: Path) -> dict[str, Any]:
    try:
        return json.loads((out / MANIFEST).read_text())
    except (FileNotFoundError, json.JSONDecodeError):
        return {}


def _write_manifest(out: Path, manifest: dict[str, Any]) -> None:
    write_text_atomic(out / MANIFEST, json.dumps(manifest, indent=1, sort_keys=True, default=str))


def load_dataset(out_dir: str | Path) -> pd.DataFrame:
    """All episodes of a dataset folder in one table (files in name order, rows in step order).

    Adds ``episode`` (the task hash, or the file stem), ``machine`` (spec name), ``soil``, ``seed``,
    ``pile_distance`` and ``pile_height`` in front of the recording columns. ``attrs["units"]`` holds the unit
    of every column.

    Raises:
        FileNotFoundError: the folder holds no ``ep-*.parquet`` file.
    """
    files = sorted(Path(out_dir).glob("ep-*.parquet"))
    if not files:
        raise FileNotFoundError(f"no episodes (ep-*.parquet) in {out_dir}")
    frames, units = [], {}
    for f in files:
        rec = read_recording(f)
        p = rec.provenance
        meta = {"episode": p.extra.get("sweep_task", {}).get("key", f.stem), "machine": (p.machine or {}).get("name"),
                "soil": (p.soil or {}).get("name"), "seed": p.seed, "pile_distance": p.env_kwargs.get("pile_distance"),
                "pile_height": p.env_kwargs.get("pile_height")}
        frames.append(rec.data.assign(**meta)[[*meta, *rec.data.columns]])
        units.update(rec.units)
    out = pd.concat(frames, ignore_index=True)
    out.attrs["units"] = {"episode": "-", "machine": "-", "soil": "-", "seed": "1", "pile_distance": "1",
                          "pile_height": "1", **units}
    return out
