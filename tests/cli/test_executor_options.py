"""``--executor``, ``--ray-address`` and ``--ray-cpus`` of ``demo``, ``zoo build`` and ``evaluate-policy`` (issue 15):
the options reach the function each command fans out through, and a bad value is a one-line error with exit code 2.

The function that fans out is replaced by a stub that records the executor it was given and stops the command with a
:class:`CommandError`, so nothing is simulated or fitted (each case runs in milliseconds once the modules are loaded);
bad values are refused before the command imports anything heavy.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any

import pytest

from scaletwin.cli import CommandError, main

#: The stub's message, printed as the command's error once the executor has been recorded.
REACHED = "stub reached"


def stub_demo(seen: dict[str, Any]) -> Callable[..., Any]:
    def fit_demo(out: Any, console: Any, workers: Any = "serial", *args: Any, **kwargs: Any) -> Any:
        seen["executor"] = workers
        raise CommandError(REACHED)

    return fit_demo


def stub_build(seen: dict[str, Any]) -> Callable[..., Any]:
    def build(cfg: Any) -> Any:
        seen["executor"] = cfg.executor
        raise CommandError(REACHED)

    return build


def stub_evaluate(seen: dict[str, Any]) -> Callable[..., Any]:
    def evaluate_policies(*args: Any, executor: Any = None, **kwargs: Any) -> Any:
        seen["executor"] = executor
        raise CommandError(REACHED)

    return evaluate_policies


#: command → (argv before the options, module attribute to stub, stub factory, the executor without options, the
#: first heavy module its ``run`` imports once the options are checked).
COMMANDS: dict[str, tuple[list[str], str, Callable[[dict[str, Any]], Callable[..., Any]], Any, str]] = {
    "demo": (["demo", "--out", "{tmp}"], "scaletwin.cli.demo.fit_demo", stub_demo, "serial", "numpy"),
    "zoo build": (["zoo", "build", "--data", "{tmp}", "--out", "{tmp}", "--registry", "{tmp}/registry.json"],
                  "zoo.build.build_zoo", stub_build, None, "torch"),
    "zoo build --product-line": (["zoo", "build", "--product-line", "--data", "{tmp}", "--out", "{tmp}",
                                  "--registry", "{tmp}/registry.json"],
                                 "zoo.product_line.build_product_line", stub_build, 2, "torch"),
    "evaluate-policy": (["evaluate-policy", "--policies", "scripted,random", "--scales", "mini", "--soils", "gravel",
                         "--episodes", "1", "--out", "{tmp}"],
                        "scaletwin_envs.evaluation.evaluate_policies", stub_evaluate, None, "rich.console"),
}


def argv_of(command: str, options: list[str], tmp: Any) -> list[str]:
    return [a.format(tmp=tmp) for a in COMMANDS[command][0]] + options


def run_command(command: str, options: list[str], tmp: Any, monkeypatch: pytest.MonkeyPatch) -> tuple[int, Any]:
    """``main`` on ``command`` with ``options``; (exit code, the executor the stub got, or a sentinel if none)."""
    _, target, factory, _, _ = COMMANDS[command]
    seen: dict[str, Any] = {}
    monkeypatch.setattr(target, factory(seen))
    code = main(argv_of(command, options, tmp))
    return code, seen.get("executor", "not reached")


@pytest.mark.parametrize("command", list(COMMANDS))
@pytest.mark.parametrize(("options", "expected"), [
    ([], "default"),
    (["--workers", "3"], 3),
    (["--workers", "serial"], "serial"),
    (["--executor", "serial"], "serial"),
    (["--executor", "local", "--workers", "2"], 2),
])
def test_local_options_reach_the_fan_out(command: str, options: list[str], expected: Any, tmp_path: Any,
                                        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    code, executor = run_command(command, options, tmp_path, monkeypatch)
    assert code == 2 and capsys.readouterr().err.strip().endswith(f"error: {REACHED}")
    assert executor == (COMMANDS[command][3] if expected == "default" else expected)


@pytest.mark.parametrize("command", list(COMMANDS))
def test_ray_options_reach_the_fan_out(command: str, tmp_path: Any, monkeypatch: pytest.MonkeyPatch,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    """A RayExecutor with the address and CPUs given (it connects only when it runs a task: no Ray starts here)."""
    pytest.importorskip("ray", reason="Ray is not installed")
    from scaletwin_envs.parallel import RayExecutor

    for options, address, cpus in ((["--executor", "ray"], None, 1.0),
                                    (["--ray-address", "ray://head:10001", "--ray-cpus", "0.5"], "ray://head:10001",
                                     0.5)):
        code, executor = run_command(command, options, tmp_path, monkeypatch)
        assert code == 2 and capsys.readouterr().err.strip().endswith(f"error: {REACHED}")
        assert isinstance(executor, RayExecutor)
        assert (executor.address, executor.num_cpus) == (address, cpus)


@pytest.mark.parametrize("command", list(COMMANDS))
@pytest.mark.parametrize(("options", "message"), [
    (["--executor", "serial", "--workers", "2"], "--workers applies to local processes only, not --executor serial"),
    (["--ray-address", "auto", "--workers", "2"], "--workers applies to local processes only, not --executor ray"),
    (["--ray-cpus", "2"], "--ray-cpus applies to --executor ray only"),
    (["--executor", "local", "--ray-address", "auto"], "--ray-address applies to --executor ray only"),
    (["--executor", "ray", "--ray-cpus", "0"], "--ray-cpus must be > 0, got 0.0"),
    (["--workers", "many"], "--workers must be an integer or 'serial', got 'many'"),
])
def test_bad_executor_options_are_one_line_errors(command: str, options: list[str], message: str, tmp_path: Any,
                                                  monkeypatch: pytest.MonkeyPatch,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    """Checked before anything heavy is imported (the command's first heavy import fails here if it comes first), so
    nothing runs."""
    monkeypatch.setitem(sys.modules, COMMANDS[command][4], None)  # ``import`` of it raises ImportError
    assert main(argv_of(command, options, tmp_path)) == 2
    assert capsys.readouterr().err == f"scaletwin {command.split(' --')[0]}: error: {message}\n"


@pytest.mark.parametrize("command", list(COMMANDS))
@pytest.mark.parametrize(("options", "message"), [
    (["--executor", "dask"], "argument --executor: invalid choice: 'dask'"),
    (["--ray-cpus", "many"], "argument --ray-cpus: invalid float value: 'many'"),
    (["--ray-address"], "argument --ray-address: expected one argument"),
])
def test_unparsable_executor_options_are_usage_errors(command: str, options: list[str], message: str, tmp_path: Any,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    """argparse's usage error: the usage, then one error line; exit code 2, no traceback."""
    with pytest.raises(SystemExit) as stop:
        main(argv_of(command, options, tmp_path))
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("usage: ") and "Traceback" not in err
    last = err.strip().splitlines()[-1]
    assert last.startswith(f"scaletwin {command.split(' --')[0]}: error: {message}")
    assert err.count("error:") == 1
