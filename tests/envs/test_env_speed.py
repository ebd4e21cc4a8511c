"""What the env's speed work rests on: the second route to the pin forces is a passive check computed on request,
the fast per-step solvers are the same equations as the reference ones, and the physics timestep is converged where
it is kept (issue 15, ``benchmarks/env_throughput.py``)."""

from __future__ import annotations

import copy
import math

import gymnasium as gym
import numpy as np
import pytest

import scaletwin_envs
from scaletwin_envs import builder
from scaletwin_envs.envs import loader_base
from scaletwin_envs.physics.newton_euler import LinkageSystem
from scaletwin_envs.physics.pile import Pile
from scaletwin_envs.physics.statics import CYLINDERS, LINKAGE_PINS
from scaletwin_envs.policies import ScriptedDigPolicy
from scaletwin_envs.recording.recorder import EpisodeRecorder, record_episode
from scaletwin_envs.rollout import run_episode
from scaletwin_envs.signals import LINKAGE_BODIES
from scaletwin_envs.specs.loader import LoaderSpec

ROUTE2 = ("F21_route2", "F31_route2", "Pf_lift_route2", "Pf_tilt_route2", "residual_F21", "residual_F31",
          "residual_Pf_lift", "residual_Pf_tilt")


def _steps(env: gym.Env, n: int, seed: int = 0) -> list[tuple[np.ndarray, float, dict]]:
    policy = ScriptedDigPolicy()
    obs, _ = env.reset(seed=seed)
    out = []
    for _ in range(n):
        obs, reward, terminated, truncated, info = env.step(policy.act(obs))
        out.append((obs, reward, info))
        if terminated or truncated:
            break
    return out


def test_route2_is_on_request_and_on_while_recorded() -> None:
    plain = gym.make(scaletwin_envs.ENV_ID, scale="mini")
    assert plain.unwrapped.two_route_check is None and not plain.unwrapped.computes_two_routes
    info = _steps(plain, 3)[-1][2]
    assert not set(ROUTE2) & set(info["signals"])  # plain stepping skips the Newton–Euler solve

    recorded = gym.make(scaletwin_envs.ENV_ID, scale="mini")
    rec = record_episode(recorded, ScriptedDigPolicy(), seed=0, max_steps=20)
    assert recorded.unwrapped.computes_two_routes
    weight = recorded.unwrapped.loader.weight
    np.testing.assert_allclose(rec.data["F21_route2"], rec.data["F21"], rtol=1e-3, atol=1e-4 * weight)
    assert rec.data["residual_F21"].max() < 1e-3

    refused = gym.make(scaletwin_envs.ENV_ID, scale="mini", two_route_check=False)
    EpisodeRecorder(refused, 0)
    assert not refused.unwrapped.request_two_route_check() and not refused.unwrapped.computes_two_routes

    always = gym.make(scaletwin_envs.ENV_ID, scale="mini", two_route_check=True)
    assert always.unwrapped.computes_two_routes
    assert set(ROUTE2) <= set(_steps(always, 1)[0][2]["signals"])


@pytest.mark.parametrize("value", [1, "yes", 0.0])
def test_two_route_check_takes_only_true_false_or_none(value: object) -> None:
    with pytest.raises(ValueError, match="two_route_check"):
        gym.make(scaletwin_envs.ENV_ID, scale="mini", two_route_check=value)


def test_route2_is_a_passive_check() -> None:
    """Observations, rewards and every route-1 signal are the same, bit for bit, with the check on or off."""
    a = _steps(gym.make(scaletwin_envs.ENV_ID, scale="er12", two_route_check=True), 60)
    b = _steps(gym.make(scaletwin_envs.ENV_ID, scale="er12", two_route_check=False), 60)
    assert len(a) == len(b)
    for (obs_a, r_a, info_a), (obs_b, r_b, info_b) in zip(a, b, strict=True):
        assert np.array_equal(obs_a, obs_b) and r_a == r_b
        assert {k: v for k, v in info_a["signals"].items() if k not in ROUTE2} == info_b["signals"]


def test_signals_are_plain_floats() -> None:
    info = _steps(gym.make(scaletwin_envs.ENV_ID, scale="mini", two_route_check=True), 2)[-1][2]
    assert all(type(v) is float for v in info["signals"].values())


def test_per_step_linkage_solver_is_the_statics_solver() -> None:
    """``solve_floats`` (the envs' route 2, every step) and ``solve`` (the statics) solve the same equations."""
    rng = np.random.default_rng(3)
    system = LinkageSystem(LINKAGE_BODIES, [(n, p, c) for n, p, c, _ in LINKAGE_PINS],
                           [(n, f"{n}_barrel", f"{n}_rod") for n, *_ in CYLINDERS])
    n, n_pins, n_slides = len(LINKAGE_BODIES), len(LINKAGE_PINS), len(CYLINDERS)
    for _ in range(20):
        mass, inertia = rng.uniform(1.0, 500.0, n), rng.uniform(0.1, 50.0, n)
        com, acc, force = rng.normal(size=(n, 2)), rng.normal(size=(n, 2)) * 3.0, rng.normal(size=(n, 2)) * 1e3
        alpha, moment = rng.normal(size=n), rng.normal(size=n) * 1e2
        pins, points = rng.normal(size=(n_pins, 2)), rng.normal(size=(n_slides, 2))
        angles = rng.uniform(0.0, 2.0 * math.pi, n_slides)
        axes = np.stack([np.cos(angles), np.sin(angles)], axis=1)
        ref = system.solve(mass, com, inertia, acc, alpha, force, moment, pins, points, axes)
        bodies = [(mass[i], *com[i], *acc[i], alpha[i], inertia[i], *force[i], moment[i]) for i in range(n)]
        x = system.solve_floats(bodies, pins.tolist(), points.tolist(), axes.tolist())
        scale = max(np.abs(x).max(), 1.0)
        for k, name in enumerate(system.pin_names):
            np.testing.assert_allclose(x[2 * k: 2 * k + 2], ref.pins[name], atol=1e-9 * scale)
        for k, name in enumerate(system.slide_names):
            assert x[2 * n_pins + 3 * k] == pytest.approx(ref.axial[name], abs=1e-9 * scale)
        assert ref.residual < 1e-9 * scale  # the system is square and consistent


def test_pile_overlap_is_the_material_inside_the_cavity() -> None:
    """Under a flat pile deeper than the cavity, the material found is the cavity's area × the strip width, to
    the grid's resolution; above the surface there is none; where the surface cuts the cavity, only what lies
    below it."""
    pile = Pile(toe_x=0.0, height=2.0, repose=1.5, length=10.0, width=1.5, cells=2001)
    pile.h[:] = 2.0
    tri = np.array([[3.0, 0.5], [4.2, 0.2], [3.6, 1.4]])
    (ax, az), (bx, bz), (cx, cz) = tri
    area = 0.5 * abs((bx - ax) * (cz - az) - (cx - ax) * (bz - az))
    _, depth = pile.overlap(tri)
    assert depth.sum() * pile.dx == pytest.approx(area, rel=5e-3)
    assert pile.overlap(tri + np.array([0.0, 2.0]))[1].sum() == 0.0  # the cavity lifted clear of the surface
    pile.h[:] = 0.8  # cuts the triangle: the part below z = 0.8 only
    xs = np.linspace(3.0, 4.2, 200_001)
    lo = np.interp(xs, [3.0, 4.2], [0.5, 0.2])
    hi = np.where(xs < 3.6, np.interp(xs, [3.0, 3.6], [0.5, 1.4]), np.interp(xs, [3.6, 4.2], [1.4, 0.2]))
    below = np.trapezoid(np.clip(np.minimum(hi, 0.8) - lo, 0.0, None), xs)
    assert pile.overlap(tri)[1].sum() * pile.dx == pytest.approx(below, rel=5e-3)


def _dig_f21(monkeypatch: pytest.MonkeyPatch, scale: str, factor: float, actions: list[np.ndarray] | None
             ) -> tuple[np.ndarray, list[np.ndarray], list[str]]:
    """F21 over a scripted dig with the physics timestep × ``factor`` (control step, soil refresh period and
    constraint time constant unchanged in seconds); ``actions`` replays a command sequence open loop."""
    froude = builder.BuildOptions.for_spec

    def for_spec(spec: LoaderSpec) -> builder.BuildOptions:
        o = froude(spec)
        return builder.BuildOptions(o.timestep * factor, o.constraint_timeconst, o.constraint_width)

    monkeypatch.setattr(loader_base.BuildOptions, "for_spec", for_spec)
    env = gym.make(scaletwin_envs.ENV_ID, scale=scale, frame_skip=round(100 / factor),
                   external_force_substeps=round(20 / factor))
    monkeypatch.undo()
    assert env.unwrapped.model.opt.timestep == pytest.approx(factor * froude(env.unwrapped.loader).timestep)
    if actions is None:
        ep = run_episode(env, ScriptedDigPolicy(), seed=0)
        return ep.signal("F21"), ep.actions, [i["phase"] for i in ep.infos]
    env.reset(seed=0)
    f21 = [env.step(a)[4]["signals"]["F21"] for a in actions]
    return np.array(f21), actions, []


def timestep_mape(monkeypatch: pytest.MonkeyPatch, scale: str, factor: float) -> float:
    """Mean absolute percentage difference of F21 over the dig rows (penetrate, curl, lift) between the Froude
    timestep and ``factor`` × it, the same commands replayed open loop (no policy feedback to amplify it)."""
    ref, actions, phases = _dig_f21(monkeypatch, scale, 1.0, None)
    other, _, _ = _dig_f21(monkeypatch, scale, factor, actions)
    rows = [k for k, p in enumerate(phases) if p in ("penetrate", "curl", "lift")]
    return float(np.mean(np.abs(other[rows] - ref[rows]) / np.abs(ref[rows]))) * 100.0


MINI_NOT_CONVERGED = pytest.mark.xfail(
    strict=True, reason="known defect, not fixed: at the mini's Froude timestep (0.38 ms) the stalled curl at relief "
    "breaks out later than at 0.19 ms and 0.095 ms, which agree with each other (F21 over the dig 0.8 % apart, "
    "against 15 % from the Froude step): the mini needs a timestep chosen by convergence, not by Froude scaling")


@pytest.mark.parametrize("scale", ["er12", "wa475", pytest.param("mini", marks=MINI_NOT_CONVERGED)])
def test_froude_timestep_is_converged(monkeypatch: pytest.MonkeyPatch, scale: str) -> None:
    """Halving the timestep moves F21 over the dig by < 1 % (mean absolute): the Froude-scaled 1 ms × √λ is a
    converged choice at the ER12 and the WA475 (not at the mini: :data:`MINI_NOT_CONVERGED`)."""
    assert timestep_mape(monkeypatch, scale, 0.5) < 1.0


def test_minis_timestep_cannot_grow(monkeypatch: pytest.MonkeyPatch) -> None:
    """The mini's timestep (1 ms × √λ = 0.38 ms) bounds its real-time factor (about 60× by ``mj_step`` alone), but
    a larger one is not justified: doubling it moves F21 over the dig by 12.5 % (mean absolute; the median row by
    2.9 %), where a numerical choice may cost 1 %. (Halving it moves F21 too: the median row by 0.9 %, the
    penetration's stalled push by up to 15 %; the mini is the least converged preset, see
    ``benchmarks/env_throughput.py``.) The bound leaves room for round-off differences between processors, which
    can shift the late, event-driven rows of the replay."""
    assert timestep_mape(monkeypatch, "mini", 2.0) > 2.0


def test_signal_reader_copy_reads_its_own_data() -> None:
    """A deep copy of a reader (with its model) keeps no views of the original's arrays: after the original steps
    on, the copy still reads the copied state, and sees a change to its own model (the payload's mass)."""
    env = gym.make(scaletwin_envs.ENV_ID, scale="mini", two_route_check=True)
    _steps(env, 5)
    u = env.unwrapped
    reader, data = u.signal_reader, u.data
    before = reader.read(data, np.zeros(2))
    twin, twin_data = copy.deepcopy(reader), copy.deepcopy(data)
    _steps(env, 3)  # the original moves on
    assert twin.read(twin_data, np.zeros(2)) == before
    payload = twin.model.body("payload").id
    twin.model.body_mass[payload] += 1.0
    assert twin.read(twin_data, np.zeros(2))["m_b"] == pytest.approx(before["m_b"] + 1.0)
