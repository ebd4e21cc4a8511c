"""Argument and output helpers shared by subcommands."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from scaletwin.cli import CommandError

if TYPE_CHECKING:  # annotations only: the command line's help must not import numpy, rich or scaling
    import numpy as np
    from rich.table import Table

    from scaling.evaluation.miniature import MiniValidation

EXECUTORS = ("local", "serial", "ray")
#: Scaling laws of ``--law`` (:func:`scaletwin_envs.specs.make_loader`); the first is the default, the only
#: one a preset machine takes.
LAWS = ("product_line", "froude")


def scale_arg(text: str) -> float | str:
    """A preset name or a float length ratio (validated by the env, which lists what is accepted)."""
    try:
        return float(text)
    except ValueError:
        return text


def add_law_arg(p: argparse.ArgumentParser) -> None:
    """``--law {product_line,froude}``, checked against the scales with :func:`check_law`."""
    p.add_argument("--law", default=LAWS[0], choices=LAWS,
                   help=f"scaling law for length-ratio scales; presets are fixed machines (default {LAWS[0]})")


def check_law(scales: Sequence[float | str], law: str, option: str) -> None:
    """Refuse ``--law`` other than the default with a preset machine, as the env would, but before any simulation.

    Args:
        scales: the scales given (presets as names, length ratios as floats).
        law: the ``--law`` value.
        option: the scales' option (``--scale``, ``--scales``), named in the message.

    Raises:
        CommandError: a non-default law with a scale that is not a length ratio.
    """
    fixed = [str(s) for s in scales if not isinstance(s, int | float)]
    if law != LAWS[0] and fixed:
        raise CommandError(f"--law {law} applies to length ratios only, and {option} {' '.join(fixed)} "
                           f"{'is a preset' if len(fixed) == 1 else 'are presets'} (fixed machines): drop --law or "
                           f"give length ratios vs the ER12 (e.g. {option} 0.3 1.5)")


def add_machine_args(p: argparse.ArgumentParser) -> None:
    """``--scale``, ``--law``, ``--soil`` and ``--seed`` of one machine (check ``--law`` with :func:`check_law`)."""
    p.add_argument("--scale", type=scale_arg, default="er12",
                   help="preset (mini, er12, wa475) or length ratio vs the ER12 in [0.05, 3] (default er12)")
    add_law_arg(p)
    p.add_argument("--soil", default="gravel", help="gravel, sand, sandy_loam or clay_loam (default gravel)")
    p.add_argument("--seed", type=int, default=0, help="reset seed (default 0)")


def add_executor_args(p: argparse.ArgumentParser) -> None:
    """``--executor {local,serial,ray}``, ``--ray-address ADDR`` and ``--ray-cpus N`` (read by
    :func:`executor_from_args`; the command defines its own ``--workers``)."""
    p.add_argument("--executor", choices=EXECUTORS, default=None,
                   help="where tasks run: local processes (default; --workers sets how many), serial (this "
                        "process) or ray")
    p.add_argument("--ray-address", metavar="ADDR", default=None,
                   help="Ray cluster to connect to (implies --executor ray): 'auto', HOST:6379 or ray://HOST:10001; "
                        "default: $RAY_ADDRESS, else a new local Ray. Give outputs as a URI (s3://...) every node "
                        "can write to")
    p.add_argument("--ray-cpus", metavar="N", type=float, default=None,
                   help="CPUs reserved per Ray task, also its torch threads (default 1)")


def executor_arg(workers: str | int | None) -> str | int | None:
    """``None`` (all cores), ``"serial"`` or a process count, from ``--workers``."""
    if workers is None or workers == "serial" or isinstance(workers, int):
        return workers
    try:
        return int(workers)
    except ValueError as exc:
        raise CommandError(f"--workers must be an integer or 'serial', got {workers!r}") from exc


def executor_from_args(args: argparse.Namespace, workers: str | int | None = None,
                       default: str | int | None = None) -> Any:
    """The executor spec of the options of :func:`add_executor_args` plus the command's ``--workers`` value:
    ``None``/an int/``"serial"`` for local runs (see :func:`scaletwin_envs.parallel.make_executor`), or a
    :class:`~scaletwin_envs.parallel.RayExecutor`. ``default`` is the local spec when neither ``--workers`` nor
    another executor is given (``None``: every core).

    Raises:
        CommandError: contradictory options, or Ray asked for but not installed.
    """
    kind = args.executor or ("ray" if args.ray_address else "local")
    if kind != "ray":
        given = [flag for flag, value in (("--ray-address", args.ray_address), ("--ray-cpus", args.ray_cpus))
                 if value is not None]
        if given:
            raise CommandError(f"{' and '.join(given)} {'apply' if len(given) > 1 else 'applies'} to --executor ray "
                               "only")
    if kind == "local":
        spec = executor_arg(workers)
        return default if spec is None else spec
    if workers is not None:
        raise CommandError(f"--workers applies to local processes only, not --executor {kind}")
    if kind == "serial":
        return "serial"
    cpus = 1.0 if args.ray_cpus is None else args.ray_cpus
    if not cpus > 0:
        raise CommandError(f"--ray-cpus must be > 0, got {args.ray_cpus}")
    try:
        from scaletwin_envs.parallel import RayExecutor

        return RayExecutor(args.ray_address, num_cpus=cpus)
    except ImportError as exc:
        raise CommandError(f"--executor ray: {exc}") from exc


def mini_table(mini: MiniValidation, title: str, env_f21: np.ndarray | None = None) -> Table:
    """A rich table: load, analytical F21, each model's signed error; the last row holds mean absolute errors."""
    from rich.table import Table

    table = Table(title=title)
    table.add_column("load (kg)", justify="right")
    table.add_column("F21 (N)", justify="right")
    if env_f21 is not None:
        table.add_column("MuJoCo F21 (N)", justify="right")
    for name in mini.predicted:
        table.add_column(f"{name} (%)", justify="right")
    for i, load in enumerate(mini.loads_kg):
        env = [f"{env_f21[i]:.3f}"] if env_f21 is not None else []
        table.add_row(f"{load:g}", f"{mini.actual[i]:.3f}", *env,
                      *(f"{mini.pct_error(n)[i]:+.2f}" for n in mini.predicted))
    env_blank = [""] if env_f21 is not None else []
    table.add_row("mean |error|", "", *env_blank, *(f"{mini.mean_abs(n):.2f}" for n in mini.predicted),
                  style="bold")
    return table
