"""Who wrote a generated file, and from which model: the generator id and the model hash.

The model hash covers the model's structure (what is compiled in,
:meth:`codegen.spec.ModelSpec.structure`) and a digest of the compiler's own
source, so a change to either regenerates the module. It is computed without
sympy, so the runtime can tell a current module from a stale one cheaply.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

VERSION = "0.1.0"


def _source_digest() -> str:
    # every module of the compiler: its stages, the spec and the formula grammar they consume
    digest = hashlib.sha256()
    for path in sorted(Path(__file__).resolve().parent.glob("*.py")):
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:12]


#: Generator id written into every header: version and a digest of the compiler's source.
GENERATOR = f"jackbox-codegen {VERSION} (source {_source_digest()})"


def model_hash(structure: dict) -> str:
    """16 hex digits identifying a model: its structure plus the generator id."""
    text = json.dumps({"generator": GENERATOR, "structure": structure}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


#: The last line of every generated module: a digest of the text above it, so a
#: truncated or damaged module is told from a whole one without importing it.
SEAL = "# sha256 of the text above: "


def seal(text: str) -> str:
    """`text` with its seal line appended."""
    return f"{text}\n{SEAL}{hashlib.sha256(text.encode()).hexdigest()}\n"


def is_sealed(text: str) -> bool:
    """Whether `text` ends with the seal of the text above it (whole and unchanged)."""
    body, _, last = text.removesuffix("\n").rpartition("\n")
    return last == f"{SEAL}{hashlib.sha256(body.encode()).hexdigest()}"
