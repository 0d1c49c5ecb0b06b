"""``aibo export minari``: logs as a Minari dataset (offline RL), one ``AiboBeacons-v0`` episode per log.

The episodes are rebuilt from the logs by :func:`aibo_gym.offline.episode_from_log` (observations in
the env's observation space, actions, rewards, terminations, truncations, infos with the true pose
when the log has it). The dataset is written to ``--out`` (default: Minari's own folder,
``MINARI_DATASETS_PATH`` or ``~/.minari/datasets``) as ``OUT/DATASET_ID``, built in a temp folder
beside it (``.aibo-PID-XXXXXXXX.tmp``: a killed export's is removed by the next one, ``aibo_core.atomic``) and
renamed into place, so an interrupted export leaves no half-written dataset; without ``--force`` the rename
refuses a dataset of the id that another export finished meanwhile. Its
metadata names the env spec (id ``AiboBeacons-v0``, with the logs' config when they share one) and
the source logs (``source_logs``); each episode's metadata names its log, policy and config.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import json
import os
import shutil
import tempfile
import warnings
from pathlib import Path
from typing import Any, Iterator

from aibo.errors import CLIError
from aibo.paths import check_files
from aibo_core import trajectory
from aibo_core.atomic import remove_stale_temps

MINARI_HINT = "pip install 'aibo-gym[minari]' (Python >= 3.11)"


def run(args) -> int:
    minari = _import_minari()
    from minari.dataset.minari_dataset import parse_dataset_id

    try:
        namespace, _, version = parse_dataset_id(args.dataset_id)
        if version is None:
            raise ValueError("no version")
    except (ValueError, TypeError):  # minari raises TypeError for an id without '-vN'
        raise CLIError(f"--dataset-id {args.dataset_id!r}: malformed; expected (namespace/)name-vN, e.g. "
                       "aibo/random-balanced-v0") from None
    root = Path(os.path.abspath(args.out or _default_root()))
    check_files(inputs=[("log", p) for p in args.logs], outputs=[], folders=[("--out", root)])
    target = root / args.dataset_id
    _check_target(target, args)
    episodes = [_episode(path) for path in args.logs]
    _check_same_spaces(episodes, args.logs)
    root.mkdir(parents=True, exist_ok=True)
    remove_stale_temps(root)  # the temp folders of killed exports
    _check_free_space(root, episodes)
    with tempfile.TemporaryDirectory(prefix=f".aibo-{os.getpid()}-", suffix=".tmp", dir=root) as tmp:
        with _datasets_path(tmp):
            dataset = _create(minari, args.dataset_id, episodes, args.logs)
            steps = dataset.total_steps
        _move_into_place(Path(tmp), root, args.dataset_id, namespace, args.force)
    print(f"wrote Minari dataset {args.dataset_id} to {target}: {len(episodes)} episode(s), {steps} steps; "
          f"read it with MINARI_DATASETS_PATH={root} and minari.load_dataset({args.dataset_id!r})")
    return 0


#: Free space an export needs: this many times its episodes' arrays, plus HEADROOM_BYTES (HDF5's chunks,
#: metadata and the infos' copies; measured: a 300-frame log holds 38 kB of arrays, its dataset 92 kB on disk).
SPACE_FACTOR = 3.0
HEADROOM_BYTES = 16 * 2**20


def _check_free_space(root: Path, episodes: list) -> None:
    """Refuse (CLIError) an export the folder's free space cannot hold: h5py on a full disk can crash the process
    (exit 139, after an HDF5 message) instead of raising."""
    arrays = sum(_nbytes([ep.observations, ep.actions, ep.rewards, ep.terminations, ep.truncations, ep.infos])
                 for _, ep in episodes)
    need = int(SPACE_FACTOR * arrays) + HEADROOM_BYTES
    free = shutil.disk_usage(root).free
    if free < need:
        raise CLIError(f"--out {root}: {free / 2**20:,.1f} MiB free, the dataset needs about {need / 2**20:,.1f} MiB; "
                       "free some space or export to another folder")


def _nbytes(value) -> int:
    """Bytes of the arrays in ``value`` (an array, or dicts and lists of them)."""
    import numpy as np

    if isinstance(value, dict):
        return sum(_nbytes(v) for v in value.values())
    if isinstance(value, (list, tuple)):
        return sum(_nbytes(v) for v in value)
    return int(np.asarray(value).nbytes)


def _import_minari():
    try:
        import minari
    except ImportError:
        raise CLIError(f"aibo export minari needs the optional 'minari' extra: {MINARI_HINT}") from None
    return minari


def _default_root() -> str:
    """Minari's datasets folder: ``MINARI_DATASETS_PATH``, else ``~/.minari/datasets``."""
    return os.environ.get("MINARI_DATASETS_PATH") or str(Path.home() / ".minari" / "datasets")


def _check_target(target: Path, args) -> None:
    """Refuse an existing dataset unless ``--force``, and a ``--force`` that would delete an input log."""
    if not target.exists():
        return
    if not args.force:
        raise CLIError(f"--dataset-id {args.dataset_id}: a dataset exists already at {target}; choose another id "
                       "(or version) or pass --force to replace it")
    for log in args.logs:
        if Path(os.path.realpath(log)).is_relative_to(os.path.realpath(target)):
            raise CLIError(f"log {log} lies inside the dataset {target} that --force would replace: an input is never deleted")


def _episode(path: str):
    """The episode of log ``path`` (CLIError naming the file and field when it has none)."""
    from aibo_gym.offline import LogNotSupported, episode_from_log

    tr = trajectory.load(path)
    try:
        return tr, episode_from_log(tr, source=path)
    except LogNotSupported as err:
        raise CLIError(str(err)) from None


def _check_same_spaces(episodes: list, paths: list[str]) -> None:
    """All episodes in one observation space: the same number of beacons."""
    width = episodes[0][1].observations.shape[1]
    for path, (_, ep) in zip(paths, episodes):
        if ep.observations.shape[1] != width:
            raise CLIError(f"{path}: field 'landmarks': {ep.observations.shape[1] - 7} beacons, but {paths[0]} has "
                           f"{width - 7}; one dataset holds one observation space")


@contextlib.contextmanager
def _datasets_path(folder: str) -> Iterator[None]:
    """Minari writes to ``MINARI_DATASETS_PATH``: point it at ``folder`` for the duration."""
    old = os.environ.get("MINARI_DATASETS_PATH")
    os.environ["MINARI_DATASETS_PATH"] = folder
    try:
        yield
    finally:
        if old is None:
            del os.environ["MINARI_DATASETS_PATH"]
        else:
            os.environ["MINARI_DATASETS_PATH"] = old


def _create(minari, dataset_id: str, episodes: list, paths: list[str]):
    """Write the dataset (under ``MINARI_DATASETS_PATH``) and its metadata; the MinariDataset."""
    from minari.data_collector import EpisodeBuffer

    from aibo_gym.envs.aibo_beacons import AiboBeaconsEnv

    buffers = [EpisodeBuffer(id=i, seed=_seed(tr), observations=ep.observations, actions=ep.actions,
                             rewards=ep.rewards, terminations=ep.terminations, truncations=ep.truncations,
                             infos=ep.infos)
               for i, (tr, ep) in enumerate(episodes)]
    env = AiboBeaconsEnv(episodes[0][1].config)
    policies = sorted({str(tr.meta.get("policy", "unknown")) for tr, _ in episodes})
    with warnings.catch_warnings():  # minari's advice to name an author, e-mail, code link and eval env
        warnings.simplefilter("ignore", UserWarning)
        dataset = minari.create_dataset_from_buffers(
            dataset_id, buffers, env=_env_spec(episodes), observation_space=env.observation_space,
            action_space=env.action_space, algorithm_name=f"aibo collect --policy {','.join(policies)}",
            description=f"AiboBeacons-v0 exploration logs (aibo-trajectory/2) exported by 'aibo export minari', one "
                        f"episode per log: {', '.join(paths)}",
        )
    dataset.storage.update_metadata({"source_logs": [str(p) for p in paths]})
    dataset.storage.update_episode_metadata([_episode_metadata(path, tr, ep) for path, (tr, ep) in zip(paths, episodes)])
    return dataset


def _seed(tr) -> int | None:
    seed = tr.meta.get("seed")
    return int(seed) if isinstance(seed, int) and not isinstance(seed, bool) else None


def _env_spec(episodes: list):
    """The registered ``AiboBeacons-v0`` spec, with the logs' config when they all share one."""
    import gymnasium as gym

    from aibo_gym import ENV_ID

    spec = gym.spec(ENV_ID)
    configs = [ep.config for _, ep in episodes]
    if all(c == configs[0] for c in configs):
        spec = dataclasses.replace(spec, kwargs={**spec.kwargs, "config": configs[0]})
    return spec


def _episode_metadata(path: str, tr, ep) -> dict[str, Any]:
    return {"source_log": str(path), "policy": str(tr.meta.get("policy", "unknown")),
            "robot_seed": int(ep.config["robot_seed"]), "config": json.dumps(ep.config)}


def _move_into_place(tmp: Path, root: Path, dataset_id: str, namespace: str | None, force: bool) -> None:
    """Rename ``tmp/ID`` to ``root/ID``, with new namespaces' metadata. Without ``force`` a dataset that appeared
    meanwhile (another export of the id) is kept and this one refused (the rename onto a folder that is not empty
    fails in one step); with ``force`` an old one is moved aside and removed only after."""
    target = root / dataset_id
    target.parent.mkdir(parents=True, exist_ok=True)
    old = None
    if force and target.exists():
        old = Path(tempfile.mkdtemp(prefix=f".aibo-{os.getpid()}-", suffix=".tmp", dir=root)) / "dataset"
        os.replace(target, old)
    try:
        os.rename(tmp / dataset_id, target)
    except OSError as exc:
        if exc.errno not in (errno.ENOTEMPTY, errno.EEXIST, errno.ENOTDIR, errno.EISDIR):
            raise
        raise CLIError(f"--dataset-id {dataset_id}: a dataset appeared at {target} while this export ran (another "
                       "export of the id?); it is kept and nothing was written; choose another id or pass --force") from None
    if old is not None:
        shutil.rmtree(old.parent)
    parts = namespace.split("/") if namespace else []
    for depth in range(1, len(parts) + 1):
        meta = Path(*parts[:depth]) / "namespace_metadata.json"
        if (tmp / meta).exists() and not (root / meta).exists():
            shutil.copy2(tmp / meta, root / meta)
