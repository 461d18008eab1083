"""Trajectories: what a simulation returns, and its ``.npz`` file (SCENES.md, "Output").

A :class:`Trajectory` is plain arrays: sample times, the 6 coordinates and
rates (a prescribed box's columns filled from its motion), the energy, and the
impact log (time and constraint index of every impulse). ``save`` writes the
``.npz`` atomically; ``load`` checks that a file has every key it needs.
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import JackboxError
from .fileio import write_atomic
from .scene import COORDS

NPZ_KEYS = ("t", "q", "qd", "energy", "impact_t", "impact_constraint", "constraint_names", "scene", "meta")
#: keys beyond SCENES.md, written by jackbox and optional when reading
EXTRA_KEYS = ("contact_t", "contact_constraint", "contact_event", "fallback_t")
#: arrays larger than this are stored, not deflated, unless save(compress=True) asks
COMPRESS_BELOW = 8 << 20
REST, RELEASE = 1, 2


@dataclass
class Trajectory:
    """A simulated trajectory. Shapes: N samples, K impulses, C constraints."""

    t: np.ndarray                   #: (N,) sample times
    q: np.ndarray                   #: (N, 6) coordinates, columns in COORDS order
    qd: np.ndarray                  #: (N, 6) rates
    energy: np.ndarray              #: (N,) kinetic + potential energy of both bodies
    impact_t: np.ndarray            #: (K,) time of every contact impulse, in order
    impact_constraint: np.ndarray   #: (K,) index into constraint_names
    constraint_names: tuple[str, ...]
    scene: str = ""                 #: the scene file's text
    meta: dict = field(default_factory=dict)
    #: (R,) times of contact mode changes (method "exact"): a contact came to
    #: rest (persistent, gap held at zero) or was released
    contact_t: np.ndarray = field(default_factory=lambda: np.empty(0))
    contact_constraint: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))
    contact_event: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))  #: 1 rest, 2 release
    #: (F, 2) start and end times of the stretches integrated by the fallback (Moreau-Jean
    #: time-stepping, first order; method "exact"): where accuracy was not the exact method's
    fallback_t: np.ndarray = field(default_factory=lambda: np.empty((0, 2)))

    coords = COORDS

    @property
    def impacts(self) -> np.ndarray:
        """Structured array of the impulses: fields ``t``, ``constraint``, ``name``."""
        out = np.empty(len(self.impact_t), dtype=[("t", float), ("constraint", int), ("name", "U16")])
        out["t"] = self.impact_t
        out["constraint"] = self.impact_constraint
        names = np.asarray(self.constraint_names, dtype="U16")
        out["name"] = names[self.impact_constraint] if len(names) else ""
        return out

    @property
    def contact_changes(self) -> np.ndarray:
        """Structured array of contact mode changes: ``t``, ``constraint``, ``name``, ``event`` ('rest'/'release')."""
        out = np.empty(len(self.contact_t), dtype=[("t", float), ("constraint", int), ("name", "U16"),
                                                   ("event", "U8")])
        out["t"] = self.contact_t
        out["constraint"] = self.contact_constraint
        names = np.asarray(self.constraint_names, dtype="U16")
        out["name"] = names[self.contact_constraint] if len(names) else ""
        out["event"] = np.where(self.contact_event == REST, "rest", "release")
        return out

    @property
    def held(self) -> tuple[str, ...]:
        """Names of the contacts persistent (held closed) at the end of the run, sorted."""
        last = {}
        for k, event in zip(self.contact_constraint, self.contact_event):
            last[int(k)] = event
        return tuple(sorted(self.constraint_names[k] for k, event in last.items() if event == REST))

    @property
    def fallback_seconds(self) -> float:
        """Simulated time integrated by the fallback (0: the exact method throughout)."""
        return float(np.sum(self.fallback_t[:, 1] - self.fallback_t[:, 0])) if len(self.fallback_t) else 0.0

    def __len__(self) -> int:
        return len(self.t)

    def __repr__(self) -> str:
        name = self.meta.get("scene", "?")
        return (f"<Trajectory {name}: {len(self.t)} samples over t = {self.t[0]:g}..{self.t[-1]:g} s, "
                f"{len(self.impact_t)} impulses>")

    def save(self, path: str | Path, compress: bool | None = None) -> Path:
        """Write the trajectory as ``.npz`` (atomically: never a half-written file).

        compress: deflate the arrays (smaller, slower), or not; by default only
        up to COMPRESS_BELOW bytes of arrays: doubles deflate by ~10% at ~20 MB/s,
        so a long run would spend far longer saving than computing.
        """
        arrays = {
            "t": self.t, "q": self.q, "qd": self.qd, "energy": self.energy,
            "impact_t": self.impact_t, "impact_constraint": self.impact_constraint,
            "constraint_names": np.asarray(self.constraint_names, dtype=str),
            "scene": np.asarray(self.scene), "meta": np.asarray(json.dumps(self.meta, sort_keys=True)),
            "contact_t": self.contact_t, "contact_constraint": self.contact_constraint,
            "contact_event": self.contact_event, "fallback_t": self.fallback_t,
        }
        if compress is not None and not isinstance(compress, (bool, np.bool_)):
            raise JackboxError(f"compress must be True, False or None (by size), got {compress!r}")
        if compress is None:
            compress = sum(a.nbytes for a in arrays.values()) < COMPRESS_BELOW
        save = np.savez_compressed if compress else np.savez
        return write_atomic(path, lambda fh: save(fh, **arrays))

    @classmethod
    def load(cls, path: str | Path) -> "Trajectory":
        """Read a ``.npz`` written by :meth:`save` (or by anything that follows SCENES.md)."""
        try:
            data = np.load(path, allow_pickle=False)
        except FileNotFoundError:
            raise JackboxError(f"{path}: no such file") from None
        except (OSError, ValueError, zipfile.BadZipFile) as exc:
            raise JackboxError(f"{path}: not a trajectory .npz ({_not_npz(path, exc)})") from None
        with data:
            missing = [k for k in NPZ_KEYS if k not in data.files]
            if missing:
                raise JackboxError(f"{path}: not a jackbox trajectory, missing {', '.join(missing)}")
            arrays = {k: data[k] for k in NPZ_KEYS + EXTRA_KEYS if k in data.files}
        try:
            meta = json.loads(str(arrays["meta"]))
        except json.JSONDecodeError as exc:
            raise JackboxError(f"{path}: meta is not JSON ({exc})") from None
        problem = _inconsistency(arrays)
        if problem:
            raise JackboxError(f"{path}: not a consistent trajectory: {problem}")
        return cls(
            t=arrays["t"], q=arrays["q"], qd=arrays["qd"], energy=arrays["energy"],
            impact_t=arrays["impact_t"], impact_constraint=arrays["impact_constraint"].astype(np.int64),
            constraint_names=tuple(str(s) for s in arrays["constraint_names"]),
            scene=str(arrays["scene"]), meta=meta,
            **{k: arrays[k].astype(np.int64) if k in ("contact_constraint", "contact_event") else arrays[k]
               for k in EXTRA_KEYS if k in arrays},
        )


def _inconsistency(arrays: dict) -> str | None:
    """What does not fit in a trajectory's arrays (shapes, lengths, contact indices), if anything."""
    n = arrays["t"].shape[0] if arrays["t"].ndim == 1 else -1
    if n < 1:
        return f"t has shape {arrays['t'].shape}, expected (n,) with n >= 1"
    for key, shape in (("q", (n, 6)), ("qd", (n, 6)), ("energy", (n,))):
        if arrays[key].shape != shape:
            return f"{key} has shape {arrays[key].shape}, expected {shape} (t has {n} samples)"
    names = arrays["constraint_names"]
    for times, index in (("impact_t", "impact_constraint"), ("contact_t", "contact_constraint")):
        if times not in arrays or index not in arrays:
            continue
        t_, k_ = arrays[times], arrays[index]
        if t_.ndim != 1 or k_.shape != t_.shape:
            return f"{times} and {index} have shapes {t_.shape} and {k_.shape}, expected one length"
        if k_.size and (not np.issubdtype(k_.dtype, np.integer) or k_.min() < 0 or k_.max() >= names.size):
            return f"{index} holds a contact index outside 0..{names.size - 1}"
    if "contact_event" in arrays and arrays["contact_event"].shape != arrays["contact_t"].shape:
        return "contact_event and contact_t have different lengths"
    if "fallback_t" in arrays and (arrays["fallback_t"].ndim != 2 or arrays["fallback_t"].shape[1:] != (2,)):
        return f"fallback_t has shape {arrays['fallback_t'].shape}, expected (F, 2)"
    return None


def _not_npz(path, exc: Exception) -> str:
    """Why NumPy could not read ``path``: its own words, unless the file is no NumPy file at all.

    NumPy takes any file that is neither a zip archive nor an ``.npy`` for a
    pickle, and with ``allow_pickle=False`` says so, advising to load it
    "unsafely": for a user who named a text file by mistake, the wrong advice.
    """
    try:
        with open(path, "rb") as fh:
            head = fh.read(6)
    except OSError:
        return str(exc)
    if head.startswith(b"PK") or head.startswith(b"\x93NUMPY"):
        return str(exc)
    return "not a NumPy .npz file"
