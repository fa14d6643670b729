"""Manifests: what an output was made from, so that a rerun can tell whether it is current.

Every sequence's output directory holds ``manifest.json``: the sha256 of every input file (or
the synthetic generator and its parameters), all parameters, the shellspline version, the
time and the size of every output file. The *key* of a sequence hashes its inputs, its
parameters and the version; an output is up to date when its manifest carries the same key and
every listed file is present with its size.
"""
from __future__ import annotations

import datetime as _dt
import hashlib
import json
from pathlib import Path

from ..version import __version__

__all__ = ["MANIFEST_FORMAT", "input_digest", "sequence_key", "read_manifest",
           "manifest_matches", "output_sizes", "now", "write_json_atomic"]

MANIFEST_FORMAT = "shellspline-batch-manifest/1"


def _sha256_file(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _sha256_json(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, separators=(",", ":"))
                          .encode()).hexdigest()


def input_digest(spec) -> dict:
    """sha256 of every input of a :class:`~shellspline.batch.job.SequenceSpec`.

    Returns
    -------
    dict
        ``{"synth", "sha256"}`` for a synthetic sequence, else ``{"keyframes": [{"path",
        "sha256"}, ...], "frames_file", "pinned_file"}`` (each ``{"path", "sha256"}`` or None).

    Raises
    ------
    OSError
        When an input file cannot be read.
    """
    if spec.source == "synth":
        return {"synth": spec.synth, "sha256": _sha256_json(spec.synth)}
    d = {"keyframes": [{"path": p, "sha256": _sha256_file(p)} for p in spec.keyframes]}
    for k in ("frames_path", "pinned_path"):
        p = getattr(spec, k)
        d[k[:-5] + "_file"] = None if p is None else {"path": p, "sha256": _sha256_file(p)}
    return d


def sequence_key(spec, digest: dict) -> str:
    """The key of a sequence: sha256 of its input hashes (not their paths), its parameters
    (:meth:`SequenceSpec.key_parameters`) and the shellspline version."""
    hashes = {"synth": digest.get("sha256")} if spec.source == "synth" else {
        "keyframes": [x["sha256"] for x in digest["keyframes"]],
        **{k: (digest[k] or {}).get("sha256") for k in ("frames_file", "pinned_file")}}
    return _sha256_json({"inputs": hashes, "parameters": spec.key_parameters(),
                         "shellspline_version": __version__})


def read_manifest(out: Path) -> dict | None:
    """The manifest of output directory ``out``, or None (missing, unreadable, other
    format)."""
    try:
        m = json.loads((out / "manifest.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return m if isinstance(m, dict) and m.get("format") == MANIFEST_FORMAT else None


def manifest_matches(out, key: str) -> dict | None:
    """The manifest of a complete output with this key, else None."""
    out = Path(out)
    m = read_manifest(out)
    if m is None or m.get("key") != key or not isinstance(m.get("outputs"), dict):
        return None
    for rel, size in m["outputs"].items():
        try:
            if (out / rel).stat().st_size != size:
                return None
        except OSError:
            return None
    return m


def output_sizes(d: Path) -> dict:
    """``{relative posix path: size}`` of every file under ``d`` but the manifest."""
    out = {}
    for p in sorted(d.rglob("*")):
        if p.is_file() and p.name != "manifest.json":
            out[p.relative_to(d).as_posix()] = p.stat().st_size
    return out


def now() -> str:
    """The local time with its UTC offset, to the second (ISO 8601)."""
    return _dt.datetime.now(_dt.timezone.utc).astimezone().isoformat(timespec="seconds")


def write_json_atomic(path: Path, obj) -> None:
    """Write ``obj`` as strict JSON (:func:`shellspline.io.sequences.jsonable`: NaN/inf as
    null; indent 2) to ``path`` atomically (:func:`shellspline.io.atomic.write_text_atomic`:
    a hidden sibling ``.<name>.tmp-*``, which
    :func:`~shellspline.batch.outroot.cleanup_leftovers` recognises, renamed over it)."""
    from ..io.atomic import write_text_atomic
    from ..io.sequences import jsonable

    text = json.dumps(jsonable(obj, str(path), finite=True), indent=2, allow_nan=False)
    write_text_atomic(path, text + "\n")
