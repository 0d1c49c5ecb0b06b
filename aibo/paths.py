"""File safety shared by every command: nothing a user had is lost, and legal names work.

Every command calls ``check_files(inputs, outputs)`` before any work. It refuses

- an output that is the same file as an input: the same path, a symlink to it or a hard link
  (``os.path.samefile``: same device and inode), so an input is never overwritten;
- two outputs that are the same file (one would clobber the other);
- an output that is an existing folder, or whose name is longer than the file system allows;
- the same input given twice under one label (e.g. a log and a symlink to it), or two logs with the same
  bytes (a copy): it would count twice;
- an output (file or folder) that cannot be written: its nearest existing folder (where missing folders are made)
  is a file, or refuses a new file (``check_writable``: read-only, no permission, ``/proc``), so a command never
  fails at its end, after all its work, on where it writes.

``check_replaceable(label, folder, names)``: a folder of outputs replaced whole
(``aibo_core.atomic.atomic_folder``) may hold only those outputs, so nothing else in it is lost; nor may it be
the current folder, one holding it, or a mount point (``--out .`` or ``--out ""``), which cannot be replaced:
refused before any work, not after it.

``checkpoint_path(out)`` derives the checkpoint file name beside a model file so that it never
exceeds the file system's NAME_MAX, however long the model's name is.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import Sequence

from aibo.errors import CLIError

#: (what the user calls it, e.g. "--out" or "log", path)
Named = tuple[str, "str | os.PathLike"]

CHECKPOINT_SUFFIX = ".checkpoint.npz"
_DEFAULT_NAME_MAX = 255


def same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """True when ``a`` and ``b`` name one file (symlinks followed, hard links by inode).

    When either does not exist yet, their fully resolved paths are compared.
    """
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.realpath(a) == os.path.realpath(b)


def same_bytes(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """True when the regular files ``a`` and ``b`` hold the same bytes (sizes compared first, then SHA-256)."""
    try:
        if not (os.path.isfile(a) and os.path.isfile(b)) or os.path.getsize(a) != os.path.getsize(b):
            return False
        return _sha256(a) == _sha256(b)
    except OSError:
        return False  # unreadable: the command's own read reports it


def _sha256(path: str | os.PathLike) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(2**20), b""):
            digest.update(block)
    return digest.hexdigest()


def name_max(folder: str | os.PathLike) -> int:
    """Longest file name (bytes) allowed in ``folder`` (or its nearest existing ancestor)."""
    folder = Path(os.path.abspath(folder))
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    try:
        return int(os.pathconf(folder, "PC_NAME_MAX"))
    except (OSError, ValueError, AttributeError):
        return _DEFAULT_NAME_MAX


#: (label, argparse attribute) of the options that name files a command reads.
INPUT_OPTIONS = (("log", "logs"), ("--init", "init"), ("--model", "model"), ("--replay", "replay"))


def declared_inputs(args, extra: Sequence[Named] = ()) -> list[Named]:
    """Every file a command reads, from its parsed options: logs, ``--init``, ``--model``, ``--replay``,
    JSON options given as a file (``aibo.options.JSONFile``), agent files of ``sb3:PATH`` policies and of
    ``--policy-params`` naming one (``AGENT_PARAMS``);
    then ``extra`` (e.g. a dataset's files). Every command passes these to ``check_files``."""
    found: list[Named] = []
    for label, attr in INPUT_OPTIONS:
        value = getattr(args, attr, None)
        for path in (value if isinstance(value, list) else [value] if value else []):
            found.append((label, path))
    for attr, value in sorted(vars(args).items()):
        path = getattr(value, "path", None)
        if isinstance(value, dict) and path:
            found.append((f"--{attr.replace('_', '-')}", path))
    for attr in ("policy", "policies"):
        for name in str(getattr(args, attr, "") or "").split(","):
            if name.strip().startswith("sb3:"):
                found += agent_files("agent", name.strip()[4:])
    params = getattr(args, "policy_params", None) or {}
    # collect: {param: value}; experiment: {policy: {param: value}}
    for group in [params] + [v for v in params.values() if isinstance(v, dict)]:
        for key in AGENT_PARAMS:
            if isinstance(group.get(key), str) and group[key]:
                found += agent_files(f"--policy-params '{key}'", group[key])
    return found + list(extra)


#: Policy parameters that name an agent file the policy reads (``explorer``'s and ``sb3``'s ``path``).
AGENT_PARAMS = ("path",)


def agent_files(label: str, agent: str) -> list[Named]:
    """The files an agent named ``agent`` may be read from: as given, with ``.zip`` added (SB3 adds it) and its
    ``.json`` description."""
    root = agent[:-4] if agent.endswith(".zip") else agent
    return [(label, agent), (label, agent + ".zip"), (label, root + ".json")]


def check_files(inputs: Sequence[Named], outputs: Sequence[Named], folders: Sequence[Named] = ()) -> None:
    """Refuse (CLIError, one line naming both) outputs that would overwrite an input or each other.

    ``folders``: output folders (created when missing) that must not be existing files.
    """
    for label, path in folders:
        if os.path.exists(path) and not os.path.isdir(path):
            raise CLIError(f"{label} {path}: is a file, not a folder")
    for i, (label, path) in enumerate(inputs):
        for other_label, other in inputs[:i]:
            if label == other_label and same_file(path, other):
                raise CLIError(f"{label} {path} is the same file as {other_label} {other}: give each {label} once")
            if label == other_label and label == "log" and same_bytes(path, other):
                raise CLIError(f"{label} {path} holds the same bytes as {other_label} {other} (a copy): its data would "
                               f"count twice; give each {label} once")
    for i, (label, path) in enumerate(outputs):
        _check_output_name(label, path)
        for in_label, in_path in inputs:
            if same_file(path, in_path):
                raise CLIError(f"{label} {path} is the same file as the {in_label} {in_path}: an input is never "
                               "overwritten; choose another output name")
        for other_label, other in outputs[:i]:
            if same_file(path, other):
                raise CLIError(f"{label} {path} is the same file as {other_label} {other}: choose another name")
    probed: set[Path] = set()
    for label, path in [*folders, *outputs]:
        check_writable(label, path, probed)


def check_writable(label: str, path: str | os.PathLike, probed: set[Path] | None = None) -> None:
    """Refuse (CLIError, one line naming ``label`` and ``path``) an output file or folder that cannot be written
    beside: the nearest existing folder above it (where its missing folders would be made, and where the atomic
    writes put their temp files) must be a folder this process can make a file in. A probe file of ours
    (``aibo_core.atomic``'s temp name, which a later write cleans if this process is killed) is made and removed at
    once: permission bits do not tell (root passes them, and ``/proc`` or a read-only mount refuse anyway).
    ``probed``: folders already found writable (one probe each)."""
    parent = Path(os.path.abspath(path)).parent
    existing = parent
    while not os.path.lexists(existing) and existing != existing.parent:
        existing = existing.parent
    if probed is not None and existing in probed:
        return
    if not existing.is_dir():
        raise CLIError(f"{label} {path}: {existing} is {'a file, ' if existing.is_file() else ''}not a folder to "
                       "write in")
    probe = existing / f".aibo-{os.getpid()}-{os.urandom(4).hex()}.tmp"  # aibo_core.atomic's temp name
    try:
        fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except OSError as exc:
        where = (f"cannot write in the folder {existing}" if existing == parent else
                 f"the folder {parent} does not exist and cannot be made in {existing}")
        raise CLIError(f"{label} {path}: {where} ({exc.strerror or exc})") from None
    os.close(fd)
    os.unlink(probe)
    if probed is not None:
        probed.add(existing)


def check_replaceable(label: str, folder: str | os.PathLike, names: Sequence[str]) -> None:
    """Refuse (CLIError) an existing ``folder`` holding anything but ``names`` (and temp files of ours):
    the folder is about to be replaced whole, and nothing else a user keeps there may be lost."""
    from aibo_core.atomic import is_stale

    where = os.path.realpath(folder)
    if os.path.commonpath([where, os.getcwd()]) == where or os.path.ismount(where):
        what = "a mount point" if os.path.ismount(where) else "the current folder" if where == os.getcwd() else \
            "a folder holding the current one"
        raise CLIError(f"{label} {str(folder) or repr('')}: is {what}; the output folder is replaced whole, which "
                       "cannot be done to it; give a new folder (e.g. --out runs/NAME)")
    try:
        entries = sorted(os.listdir(folder))
    except (FileNotFoundError, NotADirectoryError):
        return
    other = [e for e in entries if e not in names and not is_stale(e, float("inf"))]
    if other:
        more = f" and {len(other) - 1} more" if len(other) > 1 else ""
        raise CLIError(f"{label} {folder}: holds {other[0]!r}{more}, not an output of this command; the folder is "
                       "replaced whole, so give a new folder or one this command wrote")


def _check_output_name(label: str, path: str | os.PathLike) -> None:
    if not str(path):
        raise CLIError(f"{label}: an empty file name; give the file to write")
    if os.path.isdir(path):
        raise CLIError(f"{label} {path}: is a folder; give a file name")
    name = os.fsencode(Path(path).name)
    limit = name_max(Path(path).parent)
    if len(name) > limit:
        raise CLIError(f"{label} {path}: the file name is {len(name)} bytes; this file system allows at most {limit}")


def checkpoint_path(out: str | os.PathLike) -> Path:
    """``OUT.checkpoint.npz`` beside ``out``; for names too long for that, a truncated name with an
    8-hex-digit hash of the full name (``PREFIX~HASH.checkpoint.npz``), within NAME_MAX bytes."""
    out = Path(out)
    name = os.fsencode(out.name)
    limit = name_max(out.parent)
    if len(name) + len(CHECKPOINT_SUFFIX) <= limit:
        return out.with_name(out.name + CHECKPOINT_SUFFIX)
    digest = "~" + hashlib.sha256(name).hexdigest()[:8]
    keep = max(limit - len(CHECKPOINT_SUFFIX) - len(digest), 1)
    while keep > 1 and name[keep] & 0xC0 == 0x80:  # do not cut a UTF-8 character in two
        keep -= 1
    return out.with_name(os.fsdecode(name[:keep]) + digest + CHECKPOINT_SUFFIX)
