"""Files the project writes: one output rule, and atomic writes (:ref:`concepts-commands`, STYLE
17).

**The output rule**, checked by every command and writer *before* any work:

1. The output can be written: its nearest existing ancestor is a directory in which a
   file can really be created (probed with a temporary file, so a read-only file
   system or ``/proc`` is caught even for root), and nothing of another kind is in the
   way (a file where a directory goes, or a directory where a file goes).
2. Nothing the project did not write is deleted or replaced: an existing non-empty
   directory that is not one of our outputs (recognised by its marker: a checkpoint's
   ``config.json``, a dataset's split sidecars, an experiment's ``results.json``) is
   refused with a message that names it.
3. An existing output of ours is resumed (``--resume``, or the command's documented
   resume) or replaced only when asked (``--overwrite``); an existing file is replaced
   only with ``--overwrite``.
4. Writes are atomic: a temporary name beside the target, then a rename; a directory is
   swapped in whole (:func:`replace_dir`). No hidden leftovers.
5. No command writes over one of its own inputs, ``--overwrite`` or not
   (:func:`check_not_input`), and a file of a fixed format has that format's suffix
   (``check_output_file(..., suffix=".npz")``): an ``.npz`` is never written under a
   ``.csv`` name.

>>> check_output_dir("runs/ckpt", ours=checkpoint.exists, resume=args.resume,
...                  overwrite=args.overwrite)                       # doctest: +SKIP
'new'
>>> check_output_file("labels.npz", overwrite=False, suffix=".npz")   # doctest: +SKIP
'new'
>>> check_not_input("labels.npz", {"--in": "trajs.npz"})             # doctest: +SKIP

A violation raises :class:`OutputError` (a ``ValueError``), which
:func:`slotv_jax.core.cli.command` prints as one line ``error: ...`` with exit code 2.

**Readers that name what is wrong:** :func:`read_text` (UTF-8, a byte-order mark
accepted, a bad byte reported with its file and line), :func:`read_json` (a truncated
or broken file named with its line and column) and :func:`load_npz` (a missing, empty,
truncated, corrupt or non-zip ``.npz`` told apart, never a raw ``BadZipFile``).

Standard library and NumPy only (no JAX), so :mod:`slotv_jax.core.xla` can use it before
JAX starts.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
import uuid
import zipfile
import zlib
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, BinaryIO, Literal

import numpy as np

Action = Literal["new", "resume", "overwrite"]


class OutputError(ValueError):
    """An output path that cannot, or must not, be written; the message names it and the fix."""


def _probe_dir(path: Path, what: str, target: Path) -> Path:
    """The nearest existing ancestor of ``path``; raise OutputError if no file can go there."""
    probe = path.absolute()
    while not probe.exists():
        if probe.is_symlink():  # a dangling link: writing would follow it somewhere else
            raise OutputError(f"{what} {target}: {probe} is a broken symbolic link")
        probe = probe.parent
    if not probe.is_dir():
        raise OutputError(f"{what} {target}: {probe} is a file, not a directory")
    try:
        fd, tmp = tempfile.mkstemp(dir=probe, prefix=".slotv_jax-probe-")
    except OSError as e:
        reason = (e.strerror or str(e)).lower()
        raise OutputError(f"{what} {target}: cannot write in {probe} ({reason})") from None
    os.close(fd)
    os.unlink(tmp)
    return probe


def check_output_file(
    path: str | os.PathLike,
    *,
    overwrite: bool = False,
    what: str = "--out",
    suffix: str | None = None,
) -> Action:
    """Check, before any work, that the file ``path`` may be written.

    Returns "new" (nothing there) or "overwrite" (a file there and ``overwrite``). Raises
    :class:`OutputError` if ``suffix`` (e.g. ``".npz"``, the format the command writes) is
    given and the name ends otherwise, a directory is in the way, the file exists without
    ``overwrite``, or its directory cannot be written.
    """
    path = Path(path)
    if suffix is not None and path.suffix.lower() != suffix:
        got = f"one ending in {path.suffix!r}" if path.suffix else "one without a suffix"
        raise OutputError(
            f"{what} {path}: expected a name ending in {suffix} (the format written), got {got}"
        )
    if path.is_dir():
        raise OutputError(f"{what} {path}: is a directory; give a file name")
    _probe_dir(path.parent, what, path)
    if path.exists() or path.is_symlink():
        if not overwrite:
            raise OutputError(
                f"{what} {path}: the file exists; pass --overwrite to replace it, "
                f"or choose another {what}"
            )
        return "overwrite"
    return "new"


def _same_path(a: Path, b: Path) -> bool:
    """Whether ``a`` and ``b`` name one file: equal once resolved (links, ``..``), or the
    same existing file (a hard link, a case-insensitive file system)."""
    if a.resolve() == b.resolve():
        return True
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def check_not_input(
    out: str | os.PathLike,
    inputs: Mapping[str, str | os.PathLike | None],
    *,
    what: str = "--out",
    replaces_dir: bool = False,
) -> None:
    """Check, before any work, that writing ``out`` cannot touch one of the command's inputs.

    ``inputs`` maps each input's argument (``"--answers"``) to its path (``None``: not
    given). Raises :class:`OutputError` if ``out`` is an input (compared once resolved:
    symbolic links, ``..``, a hard link), even with ``--overwrite``; with ``replaces_dir``
    (``out`` is a directory the command writes or replaces whole) also if an input lies
    inside it.

    >>> check_not_input("a.csv", {"--answers": "a.csv"})  # doctest: +SKIP
    OutputError: --out a.csv: is the input --answers a.csv; ...
    """
    out = Path(out)
    for arg, inp in inputs.items():
        if inp is None:
            continue
        inp = Path(inp)
        if _same_path(out, inp):
            raise OutputError(
                f"{what} {out}: is the input {arg} {inp}; a command never writes over its "
                f"own input (--overwrite or not): choose another {what}"
            )
        if replaces_dir and out.resolve() in inp.resolve().parents:
            raise OutputError(
                f"{what} {out}: holds the input {arg} {inp}, which writing {what} would "
                f"replace; choose another {what}, or move the input out of it"
            )


def check_output_dir(
    path: str | os.PathLike,
    *,
    ours: Callable[[Path], bool],
    resume: bool = False,
    overwrite: bool = False,
    what: str = "--out",
    resume_hint: str | None = None,
) -> Action:
    """Check, before any work, that the directory ``path`` may be written.

    ``ours(path)`` says whether an existing directory is one of our outputs (its marker).
    Returns "new" (missing or empty), "resume" (ours and ``resume``) or "overwrite" (ours
    and ``overwrite``; ``overwrite`` wins). Raises :class:`OutputError` if a file is in the
    way, a non-empty directory is not ours, ours exists without ``resume`` or
    ``overwrite``, or nothing can be written there. ``resume_hint``: how a command that can
    continue an earlier output says so (e.g. "pass --resume to continue it"); without it
    the refusal offers ``--overwrite`` or another ``what``.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OutputError(f"{what} {path}: is a file, not a directory; choose another {what}")
    _probe_dir(path, what, path)
    if not path.exists() or not any(path.iterdir()):
        return "new"
    if not ours(path):
        raise OutputError(
            f"{what} {path}: a non-empty directory that slotv_jax did not write; it is left "
            f"untouched: choose another {what} (a new or empty directory)"
        )
    if overwrite:
        return "overwrite"
    if resume:
        return "resume"
    if resume_hint is None:
        raise OutputError(
            f"{what} {path}: holds an earlier output; pass --overwrite to replace it, or "
            f"choose another {what} to keep it"
        )
    raise OutputError(
        f"{what} {path}: holds an earlier output; {resume_hint}, or pass --overwrite to replace it"
    )


# Files whose presence marks a directory as an output of ours: an experiment's results
# (table1, fidelity, explainable, planning), a search's rollouts, a sample-efficiency run,
# a checkpoint's config.
RESULT_MARKERS = (
    "results.json", "rollouts.json", "sample_efficiency.json", "label_stats.json", "config.json",
)  # fmt: skip


def is_results_dir(path: str | os.PathLike, depth: int = 2) -> bool:
    """True if ``path`` (or a subdirectory within ``depth`` levels) holds a :data:`RESULT_MARKERS`
    file: an experiment's output directory, resumed by a rerun."""
    path = Path(path)
    if any((path / m).is_file() for m in RESULT_MARKERS):
        return True
    return depth > 0 and any(
        is_results_dir(p, depth - 1) for p in path.iterdir() if p.is_dir() and not p.is_symlink()
    )


def check_output_files(
    folder: str | os.PathLike,
    names: Sequence[str],
    *,
    what: str = "--out",
    ours: Mapping[str, Callable[[Path], bool]] | None = None,
    beside: str | None = None,
) -> None:
    """Check, before any work, that the files ``names`` can be written into ``folder``.

    For a command that writes named reports into a shared folder (``experiments/``): the
    folder is a directory or can be made, it can be written, and no name is a directory.
    Files of those names are regenerated; nothing else in the folder is touched. A file
    named in ``ours`` (a results document the command resumes from) that exists must
    pass its check, or the command is refused: it is somebody else's file. With
    ``beside`` (a name in ``ours``: the results document its reports are drawn from), any
    other of the ``names`` that exists must stand beside that document, ours: a report of
    that name with no results document of ours next to it is somebody else's, refused.
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise OutputError(f"{what} {folder}: is a file, not a directory; choose another {what}")
    _probe_dir(folder, what, folder)
    for name in names:
        if (folder / name).is_dir():
            raise OutputError(f"{what} {folder}: {folder / name} is a directory, not a file")
    for name, is_ours in (ours or {}).items():
        if (folder / name).exists() and not is_ours(folder / name):
            raise OutputError(
                f"{what} {folder}: {name} exists and is not ours; choose another {what}"
            )
    if beside is not None and not (folder / beside).exists():
        for name in names:
            if name != beside and (folder / name).exists():
                raise OutputError(
                    f"{what} {folder}: {name} exists beside no {beside} of ours (so it is not "
                    f"ours); choose another {what}"
                )


def temp_dir_beside(path: str | os.PathLike) -> Path:
    """A new, empty hidden directory beside ``path`` (for :func:`replace_dir`)."""
    path = Path(path).absolute()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.parent / f".{path.name}.tmp-{uuid.uuid4().hex[:8]}"
    tmp.mkdir()
    return tmp


def replace_dir(tmp: str | os.PathLike, path: str | os.PathLike) -> None:
    """Move the finished directory ``tmp`` to ``path``, replacing an earlier ``path``.

    The caller has checked that an existing ``path`` is ours. The old directory is
    renamed aside, the new one renamed in, and the old one removed, so ``path`` always
    holds a complete output (for an instant it is missing, never half-written).
    """
    tmp, path = Path(tmp), Path(path)
    if path.is_symlink() or (path.exists() and not path.is_dir()):
        raise OutputError(f"{path}: is not a directory; refusing to replace it")
    if not path.exists():
        os.replace(tmp, path)
        return
    old = path.parent / f".{path.name}.old-{uuid.uuid4().hex[:8]}"
    os.replace(path, old)
    try:
        os.replace(tmp, path)
    except BaseException:
        os.replace(old, path)
        raise
    shutil.rmtree(old)


def atomic_write(path: str | os.PathLike, write: Callable[[BinaryIO], object]) -> None:
    """Call ``write(f)`` on a temporary file beside ``path``, flush it to disk, rename it."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp creates 0600; give the usual permissions
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def write_text(path: str | os.PathLike, text: str) -> None:
    """Atomically write ``text`` (UTF-8) to ``path``."""
    atomic_write(path, lambda f: f.write(text.encode()))


def save_figure(fig, path: str | os.PathLike, **savefig_kw) -> None:
    """Atomically save a matplotlib figure; the format comes from the file suffix."""
    fmt = Path(path).suffix.lstrip(".") or "png"
    atomic_write(path, lambda f: fig.savefig(f, format=fmt, **savefig_kw))


# ------------------------------------------------------------------ readers


def read_text(path: str | os.PathLike) -> str:
    """The text of a UTF-8 file (a leading byte-order mark dropped).

    Raises ValueError naming the file and the line of the first byte that is not UTF-8
    (a spreadsheet's "CSV" in another encoding); FileNotFoundError if it is missing.
    """
    path = Path(path)
    raw = path.read_bytes()
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        line = raw[: e.start].count(b"\n") + 1
        raise ValueError(
            f"{path}, line {line}: byte 0x{raw[e.start]:02x} is not UTF-8 text; save the "
            'file as UTF-8 (in a spreadsheet: "CSV UTF-8")'
        ) from None


class _LongInteger(ValueError):
    """An integer literal longer than Python converts (``sys.get_int_max_str_digits``)."""


def _json_int(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise _LongInteger(len(text)) from None


def read_json(
    path: str | os.PathLike,
    *,
    object_pairs_hook: Callable[[list[tuple[str, Any]]], Any] | None = None,
) -> Any:
    """Parse a JSON file; ValueError names the file, line and column of a broken or
    truncated document, and the file of one nested too deeply for Python's parser (which
    raises RecursionError) or holding an integer too long to convert; FileNotFoundError if
    it is missing. ``object_pairs_hook`` (as in :func:`json.loads`) builds each object from
    its key-value pairs, duplicates included; the errors it raises pass through as they are.
    Every JSON input of the project is read here (:func:`is_json_object_with` too)."""
    path = Path(path)
    text = read_text(path)
    try:
        return json.loads(text, object_pairs_hook=object_pairs_hook, parse_int=_json_int)
    except json.JSONDecodeError as e:
        truncated = " (the file ends early: truncated?)" if e.pos >= len(text.rstrip()) else ""
        raise ValueError(
            f"{path}, line {e.lineno}, column {e.colno}: not valid JSON: {e.msg}{truncated}"
        ) from None
    except RecursionError:  # json recurses once per level: 100,000 nested brackets
        raise ValueError(
            f"{path}: not a JSON document this program reads: arrays or objects nested too deeply"
        ) from None
    except _LongInteger as e:
        raise ValueError(
            f"{path}: not a JSON document this program reads: an integer of {e.args[0]} characters"
        ) from None


def is_json_object_with(path: str | os.PathLike, keys: Sequence[str]) -> bool:
    """Whether ``path`` holds a JSON object with at least the ``keys`` (a command's results
    document, which it may resume: :func:`check_output_files`'s ``ours``)."""
    try:
        doc = read_json(path)
    except (OSError, ValueError):
        return False
    return isinstance(doc, dict) and set(keys) <= set(doc)


_ZIP_MAGIC = (b"PK\x03\x04", b"PK\x05\x06")  # a local file header; an empty archive


def load_npz(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Every array of an ``.npz`` file (no pickle), read eagerly.

    Raises FileNotFoundError for a missing path, ValueError naming the file (and the
    array) for a directory, an empty file, a file that is not a zip archive (text, a
    ``.npy``), a truncated or corrupt archive or array, or an object array.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    if path.is_dir():
        raise ValueError(f"{path}: is a directory, not an .npz file")
    with open(path, "rb") as f:
        head = f.read(4)
    if not head:
        raise ValueError(f"{path}: empty file, not an .npz archive")
    if len(head) < 4 and any(m.startswith(head) for m in _ZIP_MAGIC):
        raise ValueError(f"{path}: truncated .npz file ({len(head)} bytes)")
    if head not in _ZIP_MAGIC:
        kind = "a .npy array" if head.startswith(b"\x93NUM") else "not a zip archive"
        raise ValueError(f"{path}: not an .npz file ({kind}; write it with numpy.savez)")
    name = None
    try:
        with np.load(path, allow_pickle=False) as z:
            out = {}
            for name in z.files:
                out[name] = z[name]
                if not isinstance(out[name], np.ndarray):  # a member that is not a .npy
                    raise ValueError(f"{path}, array {name!r}: not a NumPy array")
            return out
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError, KeyError) as e:
        where = f"{path}" if name is None else f"{path}, array {name!r}"
        if "allow_pickle" in str(e) or "Object arrays" in str(e):
            raise ValueError(f"{where}: holds Python objects (pickled); not read") from None
        if str(e).startswith(str(path)):
            raise
        raise ValueError(f"{where}: truncated or corrupt .npz file ({e})") from None
