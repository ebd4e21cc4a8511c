"""Dataset sweeps: scales × soils × pile variations × seeds, one Parquet recording per episode.

Each episode is an :class:`EpisodeTask`, named by a stable hash of its parameters (``ep-<hash>.parquet``).
Episodes run through the executor seam (:func:`scaletwin_envs.parallel.make_executor`: local processes by
default, or Ray); each worker writes its own file atomically, so an interrupted sweep loses no finished episode and
leaves no partial file, and a rerun skips every episode whose file exists. ``manifest.json`` lists the sweep,
the versions and every episode's parameters and status.

The output folder is a local path or a filesystem URI (:mod:`scaletwin_envs.recording.atomic`: ``file://``,
``s3://bucket/prefix``, any pyarrow or fsspec filesystem). Workers write to it directly, so the workers of a
multi-node Ray cluster need no shared disk when it is a URI of shared storage; with a local path on such a cluster
each worker writes to its own node's disk, which the sweep detects and reports as failed episodes.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import hashlib
import importlib
import itertools
import json
import math
import time
import warnings
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import pandas as pd
import pyarrow.fs as pafs
import pyarrow.parquet as pq
from tqdm.auto import tqdm

import scaletwin_envs
from scaletwin_envs.parallel import Executor, make_executor
from scaletwin_envs.policies import ScriptedDigPolicy
from scaletwin_envs.recording.atomic import (
    Location,
    atomic_output,
    exists,
    is_local,
    is_uri,
    join,
    list_files,
    make_dirs,
    read_bytes,
    resolve,
    write_text_atomic,
)
from scaletwin_envs.recording.recorder import record_episode
from scaletwin_envs.recording.recording import Recording, read_recording, recording_from_arrow
from scaletwin_envs.recording.schema import SCHEMA_VERSION
from scaletwin_envs.specs import make_loader
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


@functools.cache
def simulation_digest() -> str:
    """sha256 (16 hex digits) of the source of every module of :mod:`scaletwin_envs`: the code that produced an
    episode. Any change of it, even a comment, names every episode anew (a rerun simulates again): a stale
    episode costs more than a repeated one."""
    root = Path(scaletwin_envs.__file__).parent
    h = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        h.update(path.relative_to(root).as_posix().encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:16]


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
    #: the code the episode is to be simulated by (:func:`simulation_digest` of the process that made the task,
    #: carried to the workers so that the file a worker writes is the one the sweep expects)
    simulation: str = field(default_factory=lambda: simulation_digest())

    def params(self) -> dict[str, Any]:
        return asdict(self)

    def machine(self) -> float | str | LoaderSpec:
        """The ``scale`` argument of the env: a preset, a length ratio, or a :class:`LoaderSpec` given as its
        dictionary (:meth:`LoaderSpec.to_dict`, e.g. a machine of the product-line design space)."""
        return LoaderSpec.from_dict(self.scale) if isinstance(self.scale, Mapping) else self.scale

    def key(self) -> str:
        """Stable hash of the parameters, the machine they name, the simulation code and the recording schema
        version (16 hex digits).

        A preset name or a length ratio names a machine through the presets, which change between versions: the
        key holds that machine's specification too, so a resumed sweep never keeps an episode of an older preset
        (a dictionary ``scale`` is the specification already). It also holds :attr:`simulation`, so an episode
        simulated by other code (physics, policies, signals) is never reused either: on 2026-11-25 a benchmark
        cache kept dig episodes whose lengths a later change of the simulator had moved."""
        params = self.params()
        if not isinstance(self.scale, Mapping):
            # no such machine (ValueError): the episode fails with make_loader's message and is reported failed
            with contextlib.suppress(ValueError):
                params["machine_spec"] = make_loader(self.scale, law=self.law).to_dict()
        text = json.dumps({**params, "schema_version": SCHEMA_VERSION}, sort_keys=True)
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

    ``out_dir`` is an absolute path or a filesystem URI (see the module docstring). Errors are returned
    (``status="failed"``), not raised, so one bad episode does not stop a sweep.
    """
    task, out_dir = job
    location = join(out_dir, task.filename)
    summary: dict[str, Any] = {"key": task.key(), "file": task.filename}
    if exists(location):
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
        write_recording(rec, location)
    except Exception as exc:  # reported in the manifest; the file is absent, so a rerun retries it
        return {**summary, "status": "failed", "error": f"{type(exc).__name__}: {exc}"}
    last = rec.data.iloc[-1] if len(rec) else {}
    return {**summary, "status": "done", "steps": len(rec), "seconds": time.perf_counter() - start,
            "fill_factor": float(last.get("fill_factor", float("nan"))),
            "sim_error": rec.provenance.extra.get("sim_error")}


def write_recording(rec: Recording, location: Location) -> None:
    """Write ``rec`` as Parquet to a path or filesystem URI, atomically (locally :meth:`Recording.to_parquet`)."""
    fs, path = resolve(location)
    if isinstance(fs, pafs.LocalFileSystem):
        rec.to_parquet(path)
        return
    with atomic_output(location) as f:
        pq.write_table(rec.to_arrow(), f, compression="zstd")


def read_recording_at(location: Location) -> Recording:
    """:func:`read_recording` of a path or filesystem URI.

    Raises:
        FileNotFoundError: no such file.  ValueError: not a scaletwin recording (see :func:`read_recording`).
    """
    fs, path = resolve(location)
    if isinstance(fs, pafs.LocalFileSystem):
        return read_recording(path)
    if not exists(location):
        raise FileNotFoundError(f"no recording at {location}")
    return recording_from_arrow(pq.read_table(path, filesystem=fs), str(location))


@dataclass
class SweepResult:
    """What a sweep did: episodes run now (failed ones included), skipped (already present) and failed, and the
    manifest. ``out_dir`` is a :class:`Path` for a local folder, the URI otherwise."""

    out_dir: Path | str
    ran: int
    skipped: int
    failed: int
    seconds: float
    manifest: dict[str, Any]


def run_sweep(spec: SweepSpec, out_dir: Location, executor: str | int | Executor | None = None,
              progress: bool = True) -> SweepResult:
    """Run every episode of ``spec`` whose file is not in ``out_dir`` yet.

    Args:
        spec: the grid.
        out_dir: dataset folder (created): a local path or a filesystem URI such as ``s3://bucket/run1`` that every
            worker can write to (see the module docstring).
        executor: see :func:`make_executor` (None: local processes on all cores, or serial for at most
            :data:`SERIAL_MAX` episodes, where process start-up would cost more than it saves).
        progress: show a tqdm bar.

    An interrupt (Ctrl-C) cancels the episodes not finished, keeps every finished one (its file, and its entry in
    ``manifest.json``) and raises ``KeyboardInterrupt``; a rerun records only what is missing.
    """
    out = _folder(out_dir)
    make_dirs(out)
    tasks = spec.tasks()
    manifest = _new_manifest(spec, tasks, out)
    todo = [t for t in tasks if manifest["episodes"][t.key()]["status"] != "done"]
    skipped, failed, start = len(tasks) - len(todo), 0, time.perf_counter()
    _write_manifest(out, manifest)
    if executor is None and len(todo) <= SERIAL_MAX:
        executor = "serial"  # starting processes costs seconds, more than a few episodes
    ex = make_executor(executor)
    if todo and is_local(out) and _multi_node(ex):
        warnings.warn(f"{out} is a local path but the executor spans several nodes: each worker writes to its own "
                      "node's disk unless the path is shared; give a URI (e.g. s3://bucket/prefix) instead",
                      stacklevel=2)
    bar = tqdm(total=len(tasks), initial=skipped, desc="episodes", unit="ep", disable=not progress)
    written = time.monotonic()
    try:
        for _, summary in ex.map_unordered(run_task, [(t, str(out)) for t in todo]):
            manifest["episodes"][summary["key"]].update(summary)
            failed += summary["status"] == "failed"
            bar.update(1)
            if time.monotonic() - written >= MANIFEST_INTERVAL:  # the files are the truth; this is the summary
                _write_manifest(out, manifest)
                written = time.monotonic()
        failed += _check_written(out, manifest, todo)
    finally:
        bar.close()
        _write_manifest(out, manifest)
    return SweepResult(Path(out) if not is_uri(out) else out, len(todo), skipped, failed,
                       time.perf_counter() - start, manifest)


def _folder(out_dir: Location) -> str:
    """A URI as given; a local path made absolute (workers may run in another working directory)."""
    return str(out_dir) if is_uri(out_dir) else str(Path(out_dir).absolute())


def _multi_node(executor: Executor) -> bool:
    check = getattr(executor, "multi_node", None)
    return bool(check()) if callable(check) else False


def _check_written(out: str, manifest: dict[str, Any], todo: list[EpisodeTask]) -> int:
    """Mark episodes a worker reported done but whose file this process cannot see (written to another node's
    disk) as failed; returns how many."""
    present = set(list_files(out, "ep-", ".parquet"))
    lost = 0
    for t in todo:
        entry = manifest["episodes"][t.key()]
        if entry["status"] == "done" and t.filename not in present:
            entry.update(status="failed", error=f"the worker reported {t.filename} written, but it is not in {out} "
                                                "(a local path on another node?); use a URI every node can reach")
            lost += 1
    return lost


def _new_manifest(spec: SweepSpec, tasks: list[EpisodeTask], out: str) -> dict[str, Any]:
    old = _read_manifest(out).get("episodes", {})
    present = set(list_files(out, "ep-", ".parquet"))
    episodes = {}
    for t in tasks:
        entry = {**t.params(), "file": t.filename, "status": "pending"}
        if t.filename in present:
            entry = {**entry, **old.get(t.key(), {}), "status": "done"}
        episodes[t.key()] = entry
    return {"format": "scaletwin.dataset", "schema_version": SCHEMA_VERSION,
            "package_version": scaletwin_envs.__version__, "spec": spec.to_dict(), "episodes": episodes}


def _read_manifest(out: str) -> dict[str, Any]:
    try:
        return json.loads(read_bytes(join(out, MANIFEST)))
    except (FileNotFoundError, json.JSONDecodeError, UnicodeDecodeError):
        return {}


def _write_manifest(out: str, manifest: dict[str, Any]) -> None:
    write_text_atomic(join(out, MANIFEST), json.dumps(manifest, indent=1, sort_keys=True, default=str))


def _num(v: Any) -> float:
    """A sort key of an optional number (missing ones first)."""
    return float(v) if v is not None else -math.inf


def load_dataset(out_dir: Location) -> pd.DataFrame:
    """All episodes of a dataset folder (a path or filesystem URI) in one table, rows in step order.

    Episodes come in the order of what they are (machine, soil, pile distance and height, seed; the file name only
    breaks ties), not of their file names: the names are hashes, which change with the recording schema or a
    preset, and an analysis that samples rows by position must not change with them.

    Adds ``episode`` (the task hash, or the file stem), ``machine`` (spec name), ``soil``, ``seed``,
    ``pile_distance`` and ``pile_height`` in front of the recording columns. ``attrs["units"]`` holds the unit
    of every column.

    Raises:
        FileNotFoundError: the folder holds no ``ep-*.parquet`` file.
    """
    files = list_files(out_dir, "ep-", ".parquet")
    if not files:
        raise FileNotFoundError(f"no episodes (ep-*.parquet) in {out_dir}")
    frames, units = [], {}
    for name in files:
        rec = read_recording_at(join(out_dir, name))
        p = rec.provenance
        stem = name.removesuffix(".parquet")
        meta = {"episode": p.extra.get("sweep_task", {}).get("key", stem), "machine": (p.machine or {}).get("name"),
                "soil": (p.soil or {}).get("name"), "seed": p.seed, "pile_distance": p.env_kwargs.get("pile_distance"),
                "pile_height": p.env_kwargs.get("pile_height")}
        frames.append(((str(meta["machine"]), str(meta["soil"]), _num(meta["pile_distance"]),
                        _num(meta["pile_height"]), _num(meta["seed"]), name),
                       rec.data.assign(**meta)[[*meta, *rec.data.columns]]))
        units.update(rec.units)
    out = pd.concat([f for _, f in sorted(frames, key=lambda kf: kf[0])], ignore_index=True)
    out.attrs["units"] = {"episode": "-", "machine": "-", "soil": "-", "seed": "1", "pile_distance": "1",
                          "pile_height": "1", **units}
    return out
