"""A small, targeted mutation check (issue 17): would the default test run catch a wrong number?

Each :class:`Mutant` is a bug of the kind a real change introduces (a force × 1.1, a sign, an inverted convention, a
hash not checked, an interval collapsed): a file, an exact source snippet, its replacement and the default-run
tests (``-m 'not slow'``, from ``pyproject.toml``) that should catch it. The script copies the repository once to a
temporary directory (no ``.git``, ``.venv`` or caches; the working tree is never touched), then for each mutant
applies it to the copy, runs ``python -m pytest <tests> -x -q`` there with ``PYTHONPATH`` on the copy and this
interpreter (the project's venv), records *killed* (a test failed) or *survived* (all passed), and restores the file.
With ``--baseline`` (the default) every distinct test selection is first run on the unmutated copy: a mutant only
counts as killed by tests that pass without it.

Not part of the default test run (it takes several minutes). Run it with low priority, e.g.::

    nice .venv/bin/python benchmarks/mutants.py                       # all, writes benchmarks/results/mutants.md
    nice .venv/bin/python benchmarks/mutants.py --only soil_blade_force_x1.1 discrepancy_reported_parameter_x2
    .venv/bin/python benchmarks/mutants.py --list

Results: ``benchmarks/results/mutants.md`` (mutant, file, tests, killed?, seconds). A snippet that no longer occurs
exactly once in its file is reported as ``stale`` (update the mutant after the code moved). Test files that do not
exist in the tree are left out of a mutant's selection and named in the table.
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_OUT = ROOT / "benchmarks" / "results" / "mutants.md"
IGNORE = shutil.ignore_patterns(".git", ".venv", "__pycache__", ".pytest_cache", ".ruff_cache", ".mypy_cache",
                                "*.egg-info", "scaletwin-*", "policy_kpis")


@dataclass(frozen=True)
class Mutant:
    """One planted bug: replace ``snippet`` (exactly once) in the first existing path of ``files`` by
    ``replacement``, and run ``tests`` (paths or node ids; ``keyword``: a ``-k`` expression)."""

    name: str
    area: str
    files: tuple[str, ...]
    snippet: str
    replacement: str
    tests: tuple[str, ...]
    keyword: str | None = None
    what: str = ""


@dataclass
class Outcome:
    mutant: Mutant
    status: str  # killed, survived, stale, error, timeout
    seconds: float = 0.0
    killed_by: str = ""
    file: str = ""
    tests: tuple[str, ...] = ()
    missing: tuple[str, ...] = ()
    detail: str = ""
    baseline: dict[str, str] = field(default_factory=dict)


SOIL = ("tests/envs/test_soil_golden.py", "tests/envs/test_dig_physics.py")
STATICS = ("tests/envs/test_kinematics_statics.py",)
FACTORS = ("tests/scaling/test_factors.py",)
ZOO = ("tests/zoo/test_tampering.py", "tests/zoo/test_scaling_shipped.py")
FITTED = ("tests/discrepancy/test_identify.py::test_fitted_parameter_brackets_the_planted_one",
          "tests/discrepancy/test_report.py")
DESIGN = ("scaletwin_envs/design_space.py", "scaletwin_envs/specs/design_space.py")
DESIGN_TESTS = ("tests/envs/test_design_space.py", "tests/scaling/test_product_line.py")

MUTANTS: tuple[Mutant, ...] = (
    # -- physics: soil ----------------------------------------------------------------------------------------------
    Mutant("soil_blade_force_x1.1", "physics", ("scaletwin_envs/physics/earthmoving.py",),
           "    p = width * (((1 - t) * quad[k]", "    p = 1.1 * width * (((1 - t) * quad[k]", SOIL,
           what="blade force of the earthmoving equation × 1.1"),
    Mutant("soil_side_drag_x1.1", "physics", ("scaletwin_envs/physics/earthmoving.py",),
           "    return 2.0 * (normal * math.tan(soil.wall_friction_angle)",
           "    return 2.2 * (normal * math.tan(soil.wall_friction_angle)", SOIL,
           what="side-plate friction and adhesion × 1.1"),
    Mutant("soil_edge_bearing_nq", "physics", ("scaletwin_envs/physics/earthmoving.py",),
           "math.tan(math.pi / 4 + phi / 2) ** 2", "math.tan(math.pi / 4 + phi / 2)", SOIL,
           what="Prandtl–Reissner N_q without the square (edge bearing)"),
    # -- physics: statics and kinematics ----------------------------------------------------------------------------
    Mutant("statics_gravity_sign", "physics", ("scaletwin_envs/physics/newton_euler.py",),
           "(force[:, 1] - mass * gravity)", "(force[:, 1] + mass * gravity)", STATICS,
           what="Newton–Euler: weight points up"),
    Mutant("statics_payload_com_mirrored", "physics", ("scaletwin_envs/physics/statics.py",),
           'com = pose.points["pin_O"] + rot(pose.bucket_pitch) @',
           'com = pose.points["pin_O"] + rot(-pose.bucket_pitch) @',
           STATICS, what="payload centre of mass rotated by −pitch"),
    Mutant("statics_breakout_limit_sign", "physics", ("scaletwin_envs/physics/statics.py",),
           "limit = -spec.tilt.max_retract_force if slope < 0", "limit = spec.tilt.max_retract_force if slope < 0",
           ("tests/envs/test_specs.py", "tests/envs/test_design_space.py"),
           what="breakout force: retracting tilt force with the wrong sign"),
    Mutant("kinematics_link_b_angle", "physics", ("scaletwin_envs/physics/kinematics.py",),
           "heading(p21_ref - bottom_ref)) - (boom + crank)", "heading(p21_ref - bottom_ref)) - (boom - crank)",
           (*STATICS, "tests/envs/test_env.py"), what="link B angle relative to the boom, not the bell crank"),
    Mutant("kinematics_tilt_ratio_inverted", "physics", ("scaletwin_envs/physics/kinematics.py",),
           "return float(r_tilt / r_b) if r_b > 0", "return float(r_b / r_tilt) if r_b > 0",
           ("tests/envs/test_design_space.py",), what="tilt linkage force ratio inverted"),
    # -- scaling factors --------------------------------------------------------------------------------------------
    Mutant("delta1_convention_inverted", "factors", ("scaling/dimensions/factors.py",),
           "delta = src / output_group.evaluate(target_rows).reshape(-1)",
           "delta = output_group.evaluate(target_rows).reshape(-1) / src", FACTORS,
           what="prediction_factor: δ1 = π1(target)/π1(source)"),
    Mutant("delta1_dataset_inverted", "factors", ("scaling/data/delta_dataset.py",),
           "return self.pi1_source / self.pi1_target", "return self.pi1_target / self.pi1_source",
           (*FACTORS, "tests/scaling/test_cli_scaling.py"), what="DeltaDataset.delta inverted"),
    Mutant("asinh_eps_halved", "factors", ("scaling/dimensions/factors.py",),
           "np.arcsinh(np.asarray(pi, dtype=float) / (2.0 * self.eps))",
           "np.arcsinh(np.asarray(pi, dtype=float) / self.eps)",
           FACTORS, what="log-distortion feature asinh(π/ε) instead of asinh(π/2ε)"),
    # -- checkpoints ------------------------------------------------------------------------------------------------
    Mutant("checkpoint_check_csv_unverified", "checkpoint", ("zoo/checkpoint.py",),
           "        path = directory / name\n        if not path.is_file():",
           '        if name == "check.csv":\n            continue\n        path = directory / name\n'
           "        if not path.is_file():", ZOO, what="sha256 of a scaling checkpoint's check.csv not verified"),
    Mutant("checkpoint_config_unverified", "checkpoint", ("zoo/checkpoint.py",),
           "        path = directory / name\n        if not path.is_file():",
           '        if name == "config.json":\n            continue\n        path = directory / name\n'
           "        if not path.is_file():", ZOO, what="sha256 of config.json not verified"),
    # -- discrepancy fit --------------------------------------------------------------------------------------------
    Mutant("discrepancy_reported_parameter_x2", "discrepancy", ("discrepancy/pipeline.py",),
           "ReportedEffect(e.name, target, e.params, result.intervals[k]",
           "ReportedEffect(e.name, target, {n: 2.0 * v for n, v in e.params.items()}, result.intervals[k]", FITTED,
           what="fitted parameters reported × 2"),
    Mutant("discrepancy_interval_collapsed", "discrepancy", ("discrepancy/search/fit.py",),
           "intervals[c.effect][c.param] = (min(a, b), max(a, b))",
           "intervals[c.effect][c.param] = (min(a, b), min(a, b))", FITTED, what="interval collapsed to its lower end"),
    Mutant("discrepancy_interval_floor_dropped", "discrepancy", ("discrepancy/search/fit.py",),
           "floor = np.array([RESOLUTION if c.log else RESOLUTION * max(abs(v), 1e-12)",
           "floor = np.array([0.0 if c.log else 0.0 * max(abs(v), 1e-12)", FITTED,
           what="interval not widened to the objective's resolution (bootstrap only)"),
    Mutant("discrepancy_gauss_newton_step_sign", "discrepancy", ("discrepancy/search/fit.py",),
           "trials = [np.clip(u + f * delta, bounds[:, 0], bounds[:, 1])",
           "trials = [np.clip(u - f * delta, bounds[:, 0], bounds[:, 1])", ("tests/discrepancy/test_fit.py",),
           what="Gauss–Newton steps uphill (polish while naming, and the final fit)"),
    # -- conformal --------------------------------------------------------------------------------------------------
    Mutant("conformal_quantile_level", "conformal", ("scaling/evaluation/conformal.py",),
           "if finite_sample else level\n", "if finite_sample else level * n_groups / (n_groups + 1)\n",
           ("tests/scaling/test_product_line.py",), keyword="conformal or quantile or group",
           what="plain group-weighted quantile taken at level·G/(G+1)"),
    # -- design space -----------------------------------------------------------------------------------------------
    Mutant("design_space_bucket_band_skipped", "design space", DESIGN,
           "    if not lo <= m3_per_t <= hi:", "    if False and not lo <= m3_per_t <= hi:", DESIGN_TESTS,
           what="bucket m³/t band not checked"),
    Mutant("design_space_tilt_ratio_band_skipped", "design space", DESIGN,
           "    if not lo <= ratio[0] <= ratio[1] <= hi:", "    if False and not lo <= ratio[0] <= ratio[1] <= hi:",
           DESIGN_TESTS, what="tilt linkage force ratio band (dead centre) not checked"),
)


def copy_repository(dest: Path) -> Path:
    """The working tree (without VCS, venv and caches) under ``dest/repo``."""
    target = dest / "repo"
    shutil.copytree(ROOT, target, ignore=IGNORE, symlinks=True)
    return target


def _selection(repo: Path, m: Mutant) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(tests that exist in ``repo``, tests left out because their file does not exist)."""
    present = tuple(t for t in m.tests if (repo / t.split("::")[0]).is_file())
    return present, tuple(t for t in m.tests if t not in present)


def run_tests(repo: Path, tests: Sequence[str], keyword: str | None, timeout: float) -> tuple[str, float, str]:
    """(status, seconds, output) of ``pytest tests -x -q`` in ``repo``; status: passed, failed, error, timeout."""
    cmd = [sys.executable, "-m", "pytest", *tests, "-x", "-q", "-p", "no:cacheprovider", "--no-header"]
    if keyword:
        cmd += ["-k", keyword]
    env = {**os.environ, "PYTHONPATH": str(repo), "PYTHONDONTWRITEBYTECODE": "1"}
    start = time.perf_counter()
    try:
        proc = subprocess.run(cmd, cwd=repo, env=env, capture_output=True, text=True, timeout=timeout, check=False)
    except subprocess.TimeoutExpired:
        return "timeout", time.perf_counter() - start, ""
    seconds = time.perf_counter() - start
    status = {0: "passed", 1: "failed"}.get(proc.returncode, f"error (pytest exit {proc.returncode})")
    return status, seconds, proc.stdout + proc.stderr


def _tail(output: str, lines: int = 3) -> str:
    return "\n".join(output.strip().splitlines()[-lines:])


def _first_failure(output: str) -> str:
    """Node id of the first failed test in pytest's short summary (``-ra``), or ""."""
    for line in output.splitlines():
        if line.startswith(("FAILED ", "ERROR ")):
            return line.split()[1]
    return ""


def check_imports(repo: Path) -> None:
    """The copy's packages, not the working tree's (editable install), are what the tests import."""
    code = "import discrepancy, scaling, scaletwin_envs, zoo; print(scaletwin_envs.__file__)"
    out = subprocess.run([sys.executable, "-c", code], cwd=repo, env={**os.environ, "PYTHONPATH": str(repo)},
                         capture_output=True, text=True, check=True).stdout.strip()
    if not Path(out).resolve().is_relative_to(repo.resolve()):
        raise RuntimeError(f"tests in the copy would import {out}, not the copy {repo}")


def apply(repo: Path, m: Mutant) -> tuple[Path | None, str]:
    """Mutate the first existing file of ``m`` in ``repo``; (path, original text), or (None, reason)."""
    path = next((repo / f for f in m.files if (repo / f).is_file()), None)
    if path is None:
        return None, f"none of {list(m.files)} exists"
    text = path.read_text(encoding="utf-8")
    count = text.count(m.snippet)
    if count != 1:
        return None, f"snippet found {count} times in {path.relative_to(repo)}"
    path.write_text(text.replace(m.snippet, m.replacement), encoding="utf-8")
    return path, text


def run(mutants: Sequence[Mutant], timeout: float, baseline: bool, log: bool = True) -> list[Outcome]:
    outcomes: list[Outcome] = []
    with tempfile.TemporaryDirectory(prefix="scaletwin-mutants-") as tmp:
        repo = copy_repository(Path(tmp))
        check_imports(repo)
        base: dict[tuple[tuple[str, ...], str | None], str] = {}
        if baseline:
            for m in mutants:
                tests, _ = _selection(repo, m)
                key = (tests, m.keyword)
                if tests and key not in base:
                    status, seconds, output = run_tests(repo, tests, m.keyword, timeout)
                    base[key] = status
                    if log:
                        print(f"baseline {' '.join(tests)} {m.keyword or ''}: {status} ({seconds:.0f} s)"
                              + ("" if status == "passed" else f"\n{_tail(output)}"), flush=True)
        for m in mutants:
            tests, missing = _selection(repo, m)
            out = Outcome(m, "error", tests=tests, missing=missing)
            path, original = apply(repo, m)
            if path is None:
                out.status, out.detail = "stale", original
            elif not tests:
                out.status, out.detail = "error", "no test file of the mutant exists"
            elif baseline and base.get((tests, m.keyword)) != "passed":
                out.status, out.detail = "error", f"baseline {base.get((tests, m.keyword))}: tests fail unmutated"
            else:
                out.file = str(path.relative_to(repo))
                status, out.seconds, output = run_tests(repo, tests, m.keyword, timeout)
                out.status = {"failed": "killed", "passed": "survived"}.get(status, status)
                out.killed_by = _first_failure(output) if status == "failed" else ""
                out.detail = "" if status in ("failed", "passed") else _tail(output)
            if path is not None:
                path.write_text(original, encoding="utf-8")
            outcomes.append(out)
            if log:
                print(f"{m.name}: {out.status} ({out.seconds:.0f} s) {out.killed_by}"
                      + (f" — {out.detail}" if out.status not in ("killed", "survived") else ""), flush=True)
    return outcomes




def markdown(outcomes: Sequence[Outcome]) -> str:
    from scaletwin_envs.host import git_revision, host_line

    killed = [o for o in outcomes if o.status == "killed"]
    survived = [o for o in outcomes if o.status == "survived"]
    other = [o for o in outcomes if o.status not in ("killed", "survived")]
    lines = ["# Mutation check (targeted mutants)", "",
             f"{dt.datetime.now().isoformat(timespec='minutes')}, commit {git_revision()}; {host_line()}.", "",
             "Produced by `benchmarks/mutants.py`: each mutant is applied alone to a copy of the repository and the "
             "listed default-run tests (`-m 'not slow'`) are run there with `pytest -x`; *killed*: a test failed.",
             "",
             f"**{len(killed)} killed, {len(survived)} survived"
             + (f", {len(other)} not run (stale or error)" if other else "") + f"** of {len(outcomes)} mutants; "
             f"{sum(o.seconds for o in outcomes):.0f} s of test time.", "",
             "| mutant | area | file | what | tests | killed? | first failing test | seconds |",
             "|---|---|---|---|---|---|---|---|"]
    for o in outcomes:
        tests = ", ".join(f"`{t}`" for t in o.tests) + (f" (-k `{o.mutant.keyword}`)" if o.mutant.keyword else "")
        if o.missing:
            tests += "; absent: " + ", ".join(f"`{t}`" for t in o.missing)
        verdict = {"killed": "yes", "survived": "**no**"}.get(o.status, o.status + (f": {o.detail}" if o.detail
                                                                                    else ""))
        file = o.file or " / ".join(o.mutant.files)
        by = f"`{o.killed_by}`" if o.killed_by else ""
        lines.append(f"| `{o.mutant.name}` | {o.mutant.area} | `{file}` | {o.mutant.what} | {tests} | {verdict} | "
                     f"{by} | {o.seconds:.0f} |")
    lines += ["", "Survivors: " + (", ".join(f"`{o.mutant.name}`" for o in survived) or "none") + "."]
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", nargs="+", metavar="NAME", help="run these mutants only")
    parser.add_argument("--list", action="store_true", help="list the mutants and exit")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"Markdown table (default {DEFAULT_OUT})")
    parser.add_argument("--timeout", type=float, default=900.0, help="seconds per pytest run (default 900)")
    parser.add_argument("--no-baseline", action="store_true", help="skip the unmutated runs of each test selection")
    args = parser.parse_args(argv)
    if args.list:
        for m in MUTANTS:
            print(f"{m.name:40s} {m.files[0]:42s} {m.what}")
        return 0
    known = {m.name: m for m in MUTANTS}
    unknown = sorted(set(args.only or ()) - set(known))
    if unknown:
        parser.error(f"unknown mutants {unknown}; see --list")
    chosen = [known[n] for n in args.only] if args.only else list(MUTANTS)
    outcomes = run(chosen, args.timeout, not args.no_baseline)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(markdown(outcomes), encoding="utf-8")
    survivors = [o.mutant.name for o in outcomes if o.status == "survived"]
    print(f"wrote {args.out}; survivors: {', '.join(survivors) or 'none'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
