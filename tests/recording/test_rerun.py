"""rerun logs: entities with one sample per step, static geometry, a stored layout, and ``rerun rrd verify``."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections import defaultdict

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from rerun.chunk import RrdReader

import scaletwin_envs
from scaletwin.cli import main
from scaletwin_envs.policies import ScriptedDigPolicy
from scaletwin_envs.recording import Provenance, import_recording, log_episode_rrd
from scaletwin_envs.recording.groups import GROUPS
from scaletwin_envs.recording.rerun_scene import SceneLogger
from scaletwin_envs.rollout import run_episode
from scaletwin_envs.signal_units import EQ10, EQ23

BODIES = ("frame", "boom", "bucket", "bell_crank", "link_b", "lift_barrel", "lift_rod", "tilt_barrel", "tilt_rod")


def read_rrd(path) -> tuple[dict[str, int], set[str], dict[str, set[str]]]:
    """Temporal rows per entity, static entities, and component columns per entity."""
    rows: dict[str, int] = defaultdict(int)
    static: set[str] = set()
    components: dict[str, set[str]] = defaultdict(set)
    for chunk in RrdReader(path).stream().collect().stream():
        if chunk.is_static:
            static.add(chunk.entity_path)
        else:
            rows[chunk.entity_path] += chunk.num_rows
        components[chunk.entity_path] |= {n for n in chunk.to_record_batch().schema.names if ":" in n}
    return rows, static, components


def rrd_verify(path) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "rerun", "rrd", "verify", str(path)]
    return subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, "CI": "1"}, timeout=60)


@pytest.fixture(scope="module")
def episode_rrd(recorded, tmp_path_factory):
    path = tmp_path_factory.mktemp("rrd") / "ep.rrd"
    return log_episode_rrd(recorded(), path), recorded()


def test_entities_hold_one_sample_per_step(episode_rrd):
    path, rec = episode_rrd
    rows, static, components = read_rrd(path)
    n = len(rec)
    for name in dict.fromkeys((*EQ10, *EQ23, "m_load", "Pf_lift_route2")):
        assert rows[f"/signals/{name}"] == n, name
        assert "SeriesLines:names" in components[f"/signals/{name}"]
    for group in GROUPS:
        assert rows[f"/signals/groups/{group}"] == n, group
    for body in BODIES:
        assert rows[f"/world/loader/{body}"] == n, body
        assert "Transform3D:translation" in components[f"/world/loader/{body}"]
        assert any(p.startswith(f"/world/loader/{body}/geometry/") for p in static), body
    assert rows["/world/bucket_load"] == n
    assert 1 <= rows["/world/pile"] <= n + 1
    changes = int((rec.data["phase"] != rec.data["phase"].shift()).sum())  # the first row counts as a change
    assert rows["/phases"] == rows["/phase"] == changes
    assert "TextLog:text" in components["/phases"]


def test_rrd_verifies_and_stores_the_layout(episode_rrd):
    path, _ = episode_rrd
    result = rrd_verify(path)
    assert result.returncode == 0, result.stdout + result.stderr
    assert len(RrdReader(path).blueprints()) == 1


def rrd_provenance(path) -> dict:
    for chunk in RrdReader(path).stream().collect().stream():
        if chunk.entity_path == "/__properties/scaletwin":
            return json.loads(chunk.to_record_batch().column("provenance")[0][0].as_py())
    raise AssertionError("no scaletwin provenance property in the .rrd")


def test_rrd_carries_provenance(episode_rrd):
    path, rec = episode_rrd
    assert Provenance.from_dict(rrd_provenance(path)) == rec.provenance


def test_imported_log_gives_signals_without_scene(recorded, tmp_path):
    rec = recorded()
    frame = rec.data[["time", "cmd_lift", "cmd_tilt", "cmd_drive", *dict.fromkeys((*EQ10, *EQ23))]]
    frame.rename(columns=lambda c: f"{c} [{rec.units[c]}]").to_csv(tmp_path / "rig.csv", index=False)
    path = log_episode_rrd(import_recording(tmp_path / "rig.csv"), tmp_path / "rig.rrd")
    rows, _, _ = read_rrd(path)
    assert rows["/signals/F21"] == len(rec) and "/world/loader/boom" not in rows
    assert rows["/signals/groups/F21_over_F31"] == len(rec)


def test_simulate_writes_rrd_and_parquet(tmp_path, capsys):
    rrd, parquet = tmp_path / "out.rrd", tmp_path / "out.parquet"
    assert main(["simulate", "--scale", "mini", "--rrd", str(rrd), "--parquet", str(parquet)]) == 0
    rows, _, _ = read_rrd(rrd)
    from scaletwin_envs.recording import read_recording

    n = len(read_recording(parquet))
    assert rows["/signals/F21"] == rows["/world/loader/bucket"] == n
    assert rrd_verify(rrd).returncode == 0
    prov = rrd_provenance(rrd)
    assert prov["seed"] == 0 and prov["machine"]["name"] == "mini" and prov["package_version"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.parquet", "out.rrd"]


def test_scene_geometry_composes_to_mujoco_geom_poses():
    """Body transform ∘ static geom pose (as logged) lands every geom where MuJoCo puts it."""
    env = gym.make(scaletwin_envs.ENV_ID, scale="mini")
    env.reset(seed=0)
    for _ in range(15):
        env.step(np.array([0.6, 0.4, 0.5], dtype=np.float32))
    m, d = env.unwrapped.model, env.unwrapped.data
    scene = SceneLogger(m)
    positions, quats = scene.poses(d)
    checked = set()
    for k, body in enumerate(scene.body_ids):
        body_rot = _mat(quats[k][[3, 0, 1, 2]])  # back to MuJoCo's w, x, y, z
        for kind, parts in scene.body_geometry(int(body)).items():
            for part in parts:
                geom_rot, local = _mat(part["quat"]), part["pos"]
                if kind == "capsules":  # rerun capsules start at their translation; MuJoCo's are centred
                    local = local + geom_rot @ np.array([0.0, 0.0, 0.5 * part["len"]])
                np.testing.assert_allclose(positions[k] + body_rot @ local, d.geom_xpos[part["geom"]], atol=1e-9)
                np.testing.assert_allclose(body_rot @ geom_rot, d.geom_xmat[part["geom"]].reshape(3, 3), atol=1e-9)
                checked.add(part["geom"])
    assert checked == {g for g in range(m.ngeom) if m.geom_bodyid[g] > 0}


def _mat(wxyz: np.ndarray) -> np.ndarray:
    out = np.zeros(9)
    mujoco.mju_quat2Mat(out, np.asarray(wxyz, dtype=np.float64))
    return out.reshape(3, 3)


def test_live_logger_to_memory(recorded):
    import rerun as rr

    from scaletwin_envs.recording import RerunLogger

    env = gym.make(scaletwin_envs.ENV_ID, scale="mini")
    rec = rr.RecordingStream("scaletwin_test")
    rec.memory_recording()
    logger = RerunLogger(env, rec, flush_every=1)
    episode = run_episode(env, ScriptedDigPolicy(), seed=0, on_step=logger)
    logger.close()
    assert len(episode.infos) == len(recorded())


def _stored_views(path) -> tuple[dict[str, tuple[str, list[str]]], dict[str, tuple[str, list[str]]]]:
    """From the blueprint stored in an .rrd: views (id → class, name, query) and containers (id → name, contents)."""
    reader = RrdReader(path)
    views: dict[str, dict] = defaultdict(dict)
    containers: dict[str, tuple[str, list[str]]] = {}
    for chunk in reader.stream(store=reader.blueprints()[0]).collect().stream():
        batch, entity = chunk.to_record_batch(), chunk.entity_path
        cols = {n: batch.column(n)[0].as_py() for n in batch.schema.names if ":" in n}
        if entity.startswith("/container/") and "ContainerBlueprint:display_name" in cols:
            containers[entity.removeprefix("/")] = (cols["ContainerBlueprint:display_name"][0],
                                                    cols["ContainerBlueprint:contents"])
        elif entity.startswith("/view/"):
            view = "/".join(entity.split("/")[1:3])
            if "ViewContents:query" in cols:
                views[view]["query"] = cols["ViewContents:query"]
            if "ViewBlueprint:display_name" in cols:
                views[view]["class"] = cols["ViewBlueprint:class_identifier"][0]
                views[view]["name"] = cols["ViewBlueprint:display_name"][0]
    return views, containers


def _unit(entity: str) -> str:
    from scaletwin_envs.recording.rerun_log import RESIDUALS_PATH
    from scaletwin_envs.signal_units import SIGNAL_UNITS

    name = entity.rsplit("/", 1)[1]
    return "N" if entity.startswith(RESIDUALS_PATH) else SIGNAL_UNITS[name]


def test_stored_layout_puts_one_unit_on_each_plot_axis(episode_rrd):
    """Every time-series plot of the stored layout holds series of a single unit ("Cylinders" put Pa beside m and
    m/s, "Bucket and load" kg beside m, so the small series lay flat at zero); every series is still plotted."""
    from scaletwin_envs.recording.rerun_log import SIGNAL_PANELS

    path, _ = episode_rrd
    views, containers = _stored_views(path)
    plotted: set[str] = set()
    series_views = [v for v in views.values() if v.get("class") == "TimeSeries" and v["query"] != ["$origin/**"]]
    for v in series_views:
        assert len({_unit(e) for e in v["query"]}) == 1, (v["name"], v["query"])
        plotted |= {e.rsplit("/", 1)[1] for e in v["query"] if not e.startswith("/signals/route2")}
    assert plotted == {n for names in SIGNAL_PANELS.values() for n in names}
    by_name = {name: [views[c]["name"] for c in contents] for name, contents in containers.values()}
    assert by_name["Cylinders"] == ["Cylinders [m]", "Cylinders [m/s]", "Cylinders [Pa]"]
    assert by_name["Bucket and load"] == ["Bucket and load [kg]", "Bucket and load [m]"]


def test_route_residual_series_is_route2_minus_route1(episode_rrd):
    """The pin and cylinder forces by both routes get a residual plot: route 2 − route 1 (N), sample by sample."""
    path, rec = episode_rrd
    series: dict[str, np.ndarray] = {}
    for chunk in RrdReader(path).stream().collect().stream():
        if chunk.entity_path.startswith("/signals/route2_minus_route1/") and not chunk.is_static:
            batch = chunk.to_record_batch()
            steps = np.asarray(batch.column("step").to_pylist())
            values = np.array([v[0] for v in batch.column("Scalars:scalars").to_pylist()])
            name = chunk.entity_path.rsplit("/", 1)[1]
            series[name] = np.concatenate([series.get(name, np.empty(0)), values[np.argsort(steps)]])
    assert set(series) == {"F21", "F31", "Pf_lift", "Pf_tilt"}
    for name, values in series.items():
        expected = rec.data[f"{name}_route2"].to_numpy() - rec.data[name].to_numpy()
        np.testing.assert_allclose(values, expected, rtol=0, atol=1e-9 * float(np.abs(rec.data[name]).max()))
        assert np.abs(values).max() < 1e-3 * float(np.abs(rec.data[name]).max())  # the routes agree ...
        assert np.abs(values).max() > 0.0  # ... yet the residual is a real series, not a copy of zeros
    views, containers = _stored_views(path)
    pin = next(contents for name, contents in containers.values() if name == "Pin forces")
    assert views[pin[1]]["query"] == ["/signals/route2_minus_route1/F21", "/signals/route2_minus_route1/F31"]
