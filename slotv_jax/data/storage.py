"""Storage of dataset splits: the Split arrays, ``DIR/<split>.npz`` and ``DIR/<split>.json``
written atomically, read back with their checksums verified.
"""

from __future__ import annotations

import dataclasses
import difflib
import hashlib
import json
import zipfile
from pathlib import Path

import numpy as np

from slotv_jax.core.defaults import LABELER_NAMES, SPLITS
from slotv_jax.core.environment import environment
from slotv_jax.core.fileio import atomic_write
from slotv_jax.core.validation import G_MAX
from slotv_jax.data.config import (
    DATA_DISTRIBUTIONS,
    PRESETS,
    DataConfig,
    _config_from_json,
    config_for,
)

FORMAT_VERSION = 1
#: Where datasets are cached, relative to the working directory: ``DATA/<preset>-<digest>``
#: (:func:`dataset_dir`). The main job (``python -m slotv_jax.experiments.table1``) and
#: ``python -m slotv_jax.data`` without ``--out`` write there; a preset name given where a
#: dataset is read (``--data quick``, ``load_split("quick", ...)``) finds it there.
DEFAULT_CACHE = Path("data")


# Arrays stored per split: name -> (dtype, shape with "N", "S", "T" symbols).
_TRAJ_ARRAYS = {
    "xyz": (np.float32, ("N", "T", 3)),
    "q": (np.float32, ("N", "T", 7)),
    "target": (np.int32, ("N",)),
    "env_id": (np.int32, ("N",)),
    "n_via": (np.int32, ("N",)),
    "residual": (np.float32, ("N",)),
}
_SCENE_ARRAYS = {
    "scene_goals": (np.float32, ("S", G_MAX, 3)),
    "scene_mask": (np.bool_, ("S", G_MAX)),
}
_LABEL_ARRAYS = {f"y_{n}": (np.float32, ("N", G_MAX)) for n in LABELER_NAMES}


# ----------------------------------------------------------------------- Split


@dataclasses.dataclass(frozen=True)
class Split:
    """One dataset split, as NumPy arrays."""

    name: str
    xyz: np.ndarray  # (N, T, 3) float32: executed TCP path (m)
    q: np.ndarray  # (N, T, 7) float32: joint configurations (rad)
    target: np.ndarray  # (N,) int32: target goal slot
    env_id: np.ndarray  # (N,) int32: index into the scene arrays
    n_via: np.ndarray  # (N,) int32: via points of the path
    residual: np.ndarray  # (N,) float32: worst IK residual of the path (m)
    scene_goals: np.ndarray  # (S, 8, 3) float32: goals of the split's scenes (m)
    scene_mask: np.ndarray  # (S, 8) bool: real goal slots, real goals first
    labels: dict[str, np.ndarray]  # labeler name -> (N, 8) float32 distributions
    meta: dict  # the JSON sidecar

    def __len__(self) -> int:
        return int(self.xyz.shape[0])

    @property
    def goals(self) -> np.ndarray:
        """(N, 8, 3) goals of each trajectory's scene."""
        return self.scene_goals[self.env_id]

    @property
    def goal_mask(self) -> np.ndarray:
        """(N, 8) real-goal mask of each trajectory's scene."""
        return self.scene_mask[self.env_id]

    def arrays(self) -> dict[str, np.ndarray]:
        """Every stored array by its file name."""
        out = {k: getattr(self, k) for k in (*_TRAJ_ARRAYS, *_SCENE_ARRAYS)}
        out.update({f"y_{k}": v for k, v in self.labels.items()})
        return out

    def subset(self, idx) -> Split:
        """The trajectories at ``idx`` (scenes kept whole)."""
        idx = np.asarray(idx)
        pick = {k: getattr(self, k)[idx] for k in _TRAJ_ARRAYS}
        return dataclasses.replace(self, **pick, labels={k: v[idx] for k, v in self.labels.items()})


# ------------------------------------------------------------------- generation


# -------------------------------------------------------------------------- I/O


def _sha256(a: np.ndarray) -> str:
    a = np.ascontiguousarray(a)
    h = hashlib.sha256()
    h.update(f"{a.dtype.str}{a.shape}".encode())
    h.update(a.tobytes())
    return h.hexdigest()


def dataset_dir(cache: str | Path, cfg: DataConfig) -> Path:
    """Where a dataset of ``cfg`` is cached below ``cache``: one directory per config digest,
    ``CACHE/<preset>-<digest>``, so that another config never reuses it."""
    return Path(cache) / f"{cfg.preset}-{cfg.digest()}"


def preset_dir(preset: str, cache: str | Path = DEFAULT_CACHE) -> Path:
    """Where the dataset of a preset's default config is cached: ``CACHE/<preset>-<digest>``,
    the folder that ``python -m slotv_jax.experiments.table1 --preset PRESET`` and
    ``python -m slotv_jax.data --preset PRESET`` write."""
    if preset not in PRESETS:
        raise ValueError(f"preset: expected one of {sorted(PRESETS)}, got {preset!r}")
    return dataset_dir(cache, PRESETS[preset]())


def data_command(cfg: DataConfig, out: str | Path | None = None) -> str | None:
    """The ``python -m slotv_jax.data`` command line that generates ``cfg`` into ``out``
    (``None``: the cache folder, :func:`dataset_dir`), or ``None`` if its options cannot
    express ``cfg`` (a config made in Python). The command is checked: the config it builds
    has ``cfg``'s digest.

    >>> data_command(PRESETS["quick"]())
    'python -m slotv_jax.data --preset quick'
    """
    if cfg.preset not in PRESETS:
        return None
    dist = next((d for d, (t, _) in DATA_DISTRIBUTIONS.items() if t == cfg.trajectory), None)
    if dist is None:
        return None
    base = PRESETS[cfg.preset]()
    opts = {"seed": cfg.seed, "n_train": cfg.n_train, "n_eval": cfg.n_eval}
    opts = {k: v for k, v in {**opts, "chunk_size": cfg.chunk_size}.items()
            if v != getattr(base, k)}  # fmt: skip
    labels = DATA_DISTRIBUTIONS[dist][1]
    betas = {k: v for k, v in dataclasses.asdict(cfg.labels).items()
             if v != getattr(labels, k)}  # fmt: skip
    try:
        again = config_for(cfg.preset, distribution=dist, **opts, labels=betas)
    except (TypeError, ValueError):
        return None
    if again.digest() != cfg.digest():
        return None
    words = ["python -m slotv_jax.data", f"--preset {cfg.preset}"]
    words += [f"--{k.replace('_', '-')} {v}" for k, v in opts.items()]
    if dist != "default":
        words.append(f"--distribution {dist}")
    words += [f"--{k.replace('_', '-')} {v}" for k, v in betas.items()]
    if out is not None and Path(out) != dataset_dir(DEFAULT_CACHE, cfg):
        words.append(f"--out {out}")
    return " ".join(words)


def find_dataset(where: str | Path, cache: str | Path = DEFAULT_CACHE) -> Path:
    """The dataset folder that ``where`` names, for every command that reads one.

    An existing folder is itself. Otherwise a preset name (``quick``, ``paper``) names the
    dataset of that preset's default config in the cache, :func:`preset_dir`
    (``data/quick-<digest>``, relative to the working directory): the one the main job
    made. Anything else is an error that names the folder looked in, the presets (the
    closest one if ``where`` looks like a misspelt one) and the command that makes it.

    >>> find_dataset("quick")  # after python -m slotv_jax.experiments.table1  # doctest: +SKIP
    PosixPath('data/quick-251c48741b67b804')
    """
    path = Path(where)
    if path.is_dir():
        return path
    if path.exists():
        raise ValueError(f"{where}: expected a dataset folder, got a file")
    if str(where) in PRESETS:
        made = preset_dir(str(where), cache)
        if is_dataset_dir(made):
            return made
        raise FileNotFoundError(_no_preset_dataset(str(where), made))
    looked = "" if path.is_absolute() else f" ({path.absolute()})"
    presets = ", ".join(PRESETS)
    if path.name in PRESETS:
        hint = f"; give the preset name alone ({path.name}) for the dataset the main job made"
    elif close := difflib.get_close_matches(path.name, PRESETS, n=1):
        hint = f", nor a preset name (the presets: {presets}; did you mean {close[0]}?)"
    else:
        hint = f", nor a preset name (the presets: {presets}, the datasets the main job makes)"
    raise FileNotFoundError(
        f"{where}: no such dataset folder{looked}{hint}; to make a dataset in this folder, "
        f"run: python -m slotv_jax.data --preset quick --out {where}"
    )


def _no_preset_dataset(preset: str, made: Path) -> str:
    """The error for a preset name whose dataset is not in the cache folder ``made`` names:
    the absolute folder looked in, how to point at the dataset, how to make it."""
    cache = made.parent
    where = (
        f"{made.absolute()}"
        if cache.is_absolute()
        else f"{made.absolute()} (a preset name is looked up in {cache}/ of the folder the "
        "command runs in)"
    )
    return (
        f"dataset {preset!r}: the {preset} preset's dataset is not in {where}; run the command "
        f"from the folder that holds {cache}/ (where the main job ran), or give the dataset's "
        f"folder instead of the name (--data DIR/{cache}/{made.name}); to make it here: "
        f"python -m slotv_jax.data --preset {preset} (the main job, python -m "
        f"slotv_jax.experiments.table1 --preset {preset}, makes it too)"
    )


def is_dataset_dir(path: str | Path) -> bool:
    """True if ``path`` holds a split written by :func:`save_split` (its marker: a split's
    ``.json`` sidecar, or its ``.npz`` alone if a run stopped between the two)."""
    return any((Path(path) / f"{n}{x}").is_file() for n in SPLITS for x in (".json", ".npz"))


def _check_dir_config(out: Path, cfg: DataConfig) -> None:
    """Refuse to mix splits of different configs in one directory."""
    for p in sorted(out.glob("*.json")):
        if p.stem not in SPLITS:
            continue
        meta = _read_json(p)
        if meta.get("config_digest") != cfg.digest():
            raise ValueError(
                f"{p}: this directory holds splits of another config "
                f"(digest {meta.get('config_digest')}, requested {cfg.digest()}); "
                "use another --out directory"
            )


def save_split(out: str | Path, split: Split, cfg: DataConfig) -> dict:
    """Write ``<split>.npz`` then its ``<split>.json`` sidecar, each atomically.

    Returns the sidecar as a reader of the file sees it.
    """
    out = Path(out)
    arrays = split.arrays()
    atomic_write(out / f"{split.name}.npz", lambda f: np.savez(f, **arrays))
    meta = {
        **split.meta,
        "format_version": FORMAT_VERSION,
        "split": split.name,
        "seed": cfg.seed,
        "config": cfg.to_json(),
        "config_digest": cfg.digest(),
        "environment": environment(),
        "arrays": {
            k: {"dtype": a.dtype.str, "shape": list(a.shape), "sha256": _sha256(a)}
            for k, a in arrays.items()
        },
    }
    blob = json.dumps(meta, indent=1, default=str).encode()
    atomic_write(out / f"{split.name}.json", lambda f: f.write(blob))
    return json.loads(blob)


def _read_json(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except FileNotFoundError as e:
        raise FileNotFoundError(
            f"{path}: split sidecar not found (was the split generated?)"
        ) from e
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise ValueError(f"{path}: corrupt JSON sidecar ({e})") from e


def has_split(directory: str | Path, name: str) -> bool:
    """Whether the dataset folder ``directory`` holds split ``name`` (its sidecar is written
    last, after the arrays, so a split with a sidecar is finished)."""
    return (Path(directory) / f"{name}.json").is_file()


def _missing_split(directory: Path, name: str) -> FileNotFoundError:
    """The error for a split that ``directory`` lacks, naming the command that makes it."""
    held = [n for n in SPLITS if has_split(directory, n)]
    where = f"{directory / f'{name}.json'}: split sidecar not found"
    if not held:
        return FileNotFoundError(
            f"{where}: {directory} holds no dataset; run: python -m slotv_jax.data "
            f"--preset quick --out {directory}"
        )
    try:
        cfg = _config_from_json(json.loads((directory / f"{held[0]}.json").read_text())["config"])
        command = data_command(cfg, directory)
    except (OSError, ValueError, KeyError, TypeError):
        command = None
    run = (
        f"run: {command} --splits {name}"
        if command
        else f"generate it with the options that made the others and --out {directory}"
    )
    return FileNotFoundError(f"{where}: {directory} holds {', '.join(held)} but not {name}; {run}")


def load_split(directory: str | Path, name: str) -> Split:
    """Read one split and verify its arrays against the sidecar's shapes and SHA-256.

    ``directory`` is a dataset folder or a preset name (``"quick"``: the dataset the main
    job made, :func:`find_dataset`).
    """
    if name not in SPLITS:
        raise ValueError(f"name: expected one of {SPLITS}, got {name!r}")
    directory = find_dataset(directory)
    if not has_split(directory, name):
        raise _missing_split(directory, name)
    meta = _read_json(directory / f"{name}.json")
    path = directory / f"{name}.npz"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: split arrays not found")
    expected = meta.get("arrays")
    if not isinstance(expected, dict):
        raise ValueError(f"{directory / f'{name}.json'}: sidecar has no 'arrays' table")
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as e:
        raise ValueError(f"{path}: corrupt or truncated file ({e})") from e
    if set(arrays) != set(expected):
        raise ValueError(
            f"{path}: arrays {sorted(arrays)} do not match the sidecar's {sorted(expected)}"
        )
    for k, a in arrays.items():
        e = expected[k]
        if a.dtype.str != e["dtype"] or list(a.shape) != e["shape"]:
            raise ValueError(
                f"{path}: array {k!r} is {a.dtype.str}{list(a.shape)}, "
                f"sidecar says {e['dtype']}{e['shape']}"
            )
        if _sha256(a) != e["sha256"]:
            raise ValueError(f"{path}: array {k!r} fails its SHA-256 checksum")
    _check_layout(path, arrays)
    labels = {n: arrays[f"y_{n}"] for n in LABELER_NAMES if f"y_{n}" in arrays}
    fields = {k: arrays[k] for k in (*_TRAJ_ARRAYS, *_SCENE_ARRAYS)}
    return Split(name=name, **fields, labels=labels, meta=meta)


def _check_layout(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Shapes agree across arrays and match the expected layout."""
    missing = [k for k in (*_TRAJ_ARRAYS, *_SCENE_ARRAYS) if k not in arrays]
    if missing:
        raise ValueError(f"{path}: missing arrays {missing}")
    sizes = {"N": arrays["xyz"].shape[0], "S": arrays["scene_goals"].shape[0]}
    sizes["T"] = arrays["xyz"].shape[1] if arrays["xyz"].ndim == 3 else -1
    for k, (dtype, shape) in {**_TRAJ_ARRAYS, **_SCENE_ARRAYS, **_LABEL_ARRAYS}.items():
        if k not in arrays:
            continue
        want = tuple(sizes.get(s, s) for s in shape)
        if arrays[k].shape != want or arrays[k].dtype != dtype:
            raise ValueError(
                f"{path}: array {k!r} should be {np.dtype(dtype).name}{want}, "
                f"got {arrays[k].dtype.name}{arrays[k].shape}"
            )
    env = arrays["env_id"]
    if env.size and (env.min() < 0 or env.max() >= sizes["S"]):
        raise ValueError(f"{path}: env_id outside 0..{sizes['S'] - 1}")
