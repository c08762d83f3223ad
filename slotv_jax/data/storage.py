"""Storage of dataset splits: the Split arrays, ``DIR/<split>.npz`` and ``DIR/<split>.json``
written atomically, read back with their checksums verified.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import zipfile
from pathlib import Path

import numpy as np

from slotv_jax.core.defaults import LABELER_NAMES, SPLITS
from slotv_jax.core.environment import environment
from slotv_jax.core.fileio import atomic_write
from slotv_jax.core.validation import G_MAX
from slotv_jax.data.config import DataConfig

FORMAT_VERSION = 1


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


def load_split(directory: str | Path, name: str) -> Split:
    """Read one split and verify its arrays against the sidecar's shapes and SHA-256."""
    if name not in SPLITS:
        raise ValueError(f"name: expected one of {SPLITS}, got {name!r}")
    directory = Path(directory)
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
