"""Logs as offline-RL episodes (``aibo_gym.offline``) and ``aibo export minari`` end to end."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from aibo.cli import main
from aibo_core import trajectory
from aibo_core.actions import A_TURN, B_DIRECTION
from aibo_gym.collect import collect, replay
from aibo_gym.envs.aibo_beacons import AiboBeaconsEnv
from aibo_gym.offline import LogNotSupported, episode_from_log
from tests._diffdrive import diff_drive_log

FORWARD = 8 * int(np.flatnonzero(A_TURN == 0)[0]) + int(np.flatnonzero(B_DIRECTION == 0)[0])  # walk straight ahead


def step_env(tr):
    """Step the env the log came from through its commands: (observations, rewards, terminated, truncated, poses)."""
    env = AiboBeaconsEnv(tr.meta["config"])
    obs, info = env.reset(seed=tr.meta["seed"])
    out = {"obs": [obs], "reward": [], "terminated": [], "truncated": [], "pose": [info["pose"]]}
    for a in tr.actions:
        obs, r, term, trunc, info = env.step(int(a))
        for key, value in (("obs", obs), ("reward", r), ("terminated", term), ("truncated", trunc), ("pose", info["pose"])):
            out[key].append(value)
    return {k: np.array(v) for k, v in out.items()}


@pytest.mark.parametrize("config", [{}, {"reward": "explore", "effects": {"false_sightings": {}}}])
def test_episode_is_what_the_env_returned(config):
    tr = collect(config, steps=1200, seed=4, policy="random-balanced")
    ep, env = episode_from_log(tr, "log.npz"), step_env(tr)
    assert np.array_equal(ep.observations, env["obs"])  # bit for bit, float32
    np.testing.assert_array_equal(ep.rewards, env["reward"])
    assert np.array_equal(ep.actions, tr.actions) and np.array_equal(ep.infos["pose"], env["pose"])
    assert not ep.terminations.any() and ep.truncations.tolist() == [False] * 1199 + [True]
    assert ep.infos["sightings"]["count"].sum() == tr.n_sightings
    if config:
        assert ep.rewards.any() and ep.infos["rewards"]["coverage"].sum() > 0


def test_episode_ends_terminated_when_the_robot_left_the_field():
    config = {"walls": "none", "start_pose": [2600.0, 0.0, 0.0]}
    tr = replay(config, np.full(600, FORWARD), seed=1)  # straight ahead, out across the x = 2700 mm edge
    env = step_env(tr)
    assert env["terminated"][-1] and tr.n_frames < 600  # the env ended the episode
    ep = episode_from_log(tr, "log.npz")
    assert ep.terminations[-1] and not ep.truncations.any()


def test_unsupported_logs_are_named():
    with pytest.raises(LogNotSupported, match="cont.npz: field 'controls'.*discrete"):
        episode_from_log(diff_drive_log(seconds=5.0), "cont.npz")
    tr = collect({}, steps=50, seed=0)
    tr.head_pan = None
    with pytest.raises(LogNotSupported, match="field 'head_pan'"):
        episode_from_log(tr, "nopan.npz")


def test_export_without_minari_names_the_extra(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "minari", None)  # import minari raises ImportError
    assert main(["export", "minari", str(tmp_path / "a.npz"), "--dataset-id", "x-v0", "--out", str(tmp_path)]) == 2
    assert "optional 'minari' extra" in capsys.readouterr().err


# ---------------------------------------------------------------- with minari installed
@pytest.fixture
def minari(tmp_path, monkeypatch):
    mod = pytest.importorskip("minari", reason="the optional 'minari' extra is not installed")
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "default-root"))
    return mod


@pytest.fixture
def logs(tmp_path):
    paths = [tmp_path / "a.npz", tmp_path / "b.npz"]
    for seed, path in enumerate(paths):
        assert main(["collect", "--steps", "900", "--seed", str(seed), "--out", str(path)]) == 0
    return paths


def test_export_round_trip(minari, logs, tmp_path, monkeypatch):
    out = tmp_path / "datasets"
    assert main(["export", "minari", *map(str, logs), "--dataset-id", "aibo/explore-v0", "--out", str(out)]) == 0
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(out))
    ds = minari.load_dataset("aibo/explore-v0")
    assert ds.total_episodes == 2 and ds.total_steps == 1800
    assert ds.spec.env_spec.id == "AiboBeacons-v0"
    log_config = AiboBeaconsEnv(trajectory.load(logs[0]).meta["config"]).config
    assert ds.recover_environment().unwrapped.config == log_config  # the spec carries the logs' config
    assert ds.storage.metadata["source_logs"] == [str(p) for p in logs]
    space = AiboBeaconsEnv().observation_space
    for path, episode in zip(logs, ds.iterate_episodes()):
        tr = trajectory.load(path)
        assert np.array_equal(episode.actions, tr.actions)
        assert episode.observations.shape == (901, space.shape[0]) and all(space.contains(o) for o in episode.observations)
        # the sighting columns, read straight from the log: beacon one-hot, height px, angle rad, seen flag
        b = space.shape[0] - 7
        frames, first = np.unique(tr.sighting_frame, return_index=True)
        seen = episode.observations[frames + 1]
        assert np.array_equal(seen[np.arange(len(frames)), tr.sighting_landmark[first]], np.ones(len(frames)))
        np.testing.assert_allclose(seen[:, b], np.clip(tr.sighting_value[first, 0], -1000, 1000), rtol=1e-6)
        np.testing.assert_allclose(seen[:, b + 1], tr.sighting_value[first, 1], atol=1e-6)
        assert episode.observations[:, b + 2].sum() == len(frames)
        np.testing.assert_allclose(episode.observations[1:, b + 3], tr.head_pan, atol=1e-6)
        np.testing.assert_array_equal(episode.infos["pose"], tr.pose)
        assert episode.truncations[-1] and not episode.terminations.any() and not episode.rewards.any()
    assert [m["source_log"] for m in ds.storage.get_episode_metadata([0, 1])] == [str(p) for p in logs]
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no temp folder left


def test_export_refuses_an_existing_dataset_unless_forced(minari, logs, tmp_path, monkeypatch, capsys):
    out = tmp_path / "datasets"
    args = ["export", "minari", str(logs[0]), "--dataset-id", "explore-v1", "--out", str(out)]
    assert main(args) == 0
    assert main(args[:3] + [str(logs[1])] + args[3:]) == 2
    err = capsys.readouterr().err
    assert "--dataset-id explore-v1: a dataset exists already" in err and "--force" in err and err.count("\n") == 1
    assert main(args[:3] + [str(logs[1])] + args[3:] + ["--force"]) == 0
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(out))
    assert minari.load_dataset("explore-v1").total_episodes == 2


def test_export_defaults_to_minaris_folder(minari, logs, tmp_path):
    assert main(["export", "minari", str(logs[0]), "--dataset-id", "explore-v0"]) == 0
    assert minari.load_dataset("explore-v0").total_steps == 900  # MINARI_DATASETS_PATH (the fixture's)
    assert (tmp_path / "default-root" / "explore-v0").is_dir()


def test_export_bad_input_is_one_line(minari, logs, tmp_path, capsys):
    out = str(tmp_path / "datasets")
    assert main(["export", "minari", str(logs[0]), "--dataset-id", "no version", "--out", out]) == 2
    assert "--dataset-id 'no version': malformed" in capsys.readouterr().err
    cont = tmp_path / "cont.npz"
    trajectory.save(diff_drive_log(seconds=5.0), cont)
    assert main(["export", "minari", str(logs[0]), str(cont), "--dataset-id", "x-v0", "--out", out]) == 2
    err = capsys.readouterr().err
    assert f"{cont}: field 'controls'" in err and err.count("\n") == 1
    assert not (tmp_path / "datasets" / "x-v0").exists()
    assert main(["export", "minari", str(logs[0]), "--dataset-id", "x-v0", "--out", str(logs[1])]) == 2
    assert f"--out {logs[1]}: is a file, not a folder" in capsys.readouterr().err


def test_blind_logs_export_without_pose(minari, tmp_path, monkeypatch):
    log = tmp_path / "blind.npz"
    assert main(["collect", "--steps", "300", "--seed", "1", "--blind", "--out", str(log)]) == 0
    assert main(["export", "minari", str(log), "--dataset-id", "blind-v0"]) == 0
    episode = next(minari.load_dataset("blind-v0").iterate_episodes())
    assert "pose" not in episode.infos and episode.observations.shape == (301, 11)


def test_a_dataset_another_export_finished_meanwhile_is_kept(minari, logs, tmp_path, monkeypatch, capsys):
    """Two exports of one id without --force: the existence check before the episodes are built passes for both;
    the second to finish is refused (it replaced the first's dataset) and leaves no temp folder."""
    from aibo.commands import export

    out = tmp_path / "datasets"
    real, raced = export._create, []

    def racing(*args, **kwargs):
        if not raced:  # the other export runs to the end while this one builds its dataset
            raced.append(None)
            raced[0] = main(["export", "minari", str(logs[1]), "--dataset-id", "race-v0", "--out", str(out)])
        return real(*args, **kwargs)

    monkeypatch.setattr(export, "_create", racing)
    assert main(["export", "minari", str(logs[0]), "--dataset-id", "race-v0", "--out", str(out)]) == 2
    assert raced == [0]
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--dataset-id race-v0: a dataset appeared at" in err[0] and "--force" in err[0]
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(out))
    assert minari.load_dataset("race-v0").storage.metadata["source_logs"] == [str(logs[1])]
    assert not [p for p in out.iterdir() if p.name.startswith(".")]


def test_export_refuses_a_disk_too_full_and_cleans_killed_exports(minari, logs, tmp_path, monkeypatch, capsys):
    """h5py on a full disk can crash the process (exit 139): the free space is checked first. A killed export's
    temp folder (its process gone) is removed by the next export."""
    import os
    import shutil
    import time

    from aibo.commands import export

    out = tmp_path / "datasets"
    stale = out / ".aibo-999999999-abcdefgh.tmp"
    (stale / "x-v0").mkdir(parents=True)
    os.utime(stale, (time.time() - 3600, time.time() - 3600))
    usage = shutil.disk_usage(tmp_path)
    monkeypatch.setattr(export.shutil, "disk_usage", lambda path: usage._replace(free=2**20))
    assert main(["export", "minari", str(logs[0]), "--dataset-id", "x-v0", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"--out {out}: 1.0 MiB free, the dataset needs about" in err and err.count("\n") == 1
    assert sorted(p.name for p in out.iterdir()) == []  # nothing written, the killed export's folder removed


@pytest.mark.parametrize("dataset_id", ["noversion", "name-vx", "-v0"])
def test_export_a_dataset_id_without_a_version_is_one_line(minari, logs, tmp_path, capsys, dataset_id):
    assert main(["export", "minari", str(logs[0]), f"--dataset-id={dataset_id}", "--out", str(tmp_path / "d")]) == 2
    err = capsys.readouterr().err
    assert f"--dataset-id {dataset_id!r}: malformed" in err and err.count("\n") == 1
