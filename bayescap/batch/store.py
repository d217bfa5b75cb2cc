"""The output folder of a batch (``fit_many(..., out=DIR)``, ``bayescap fit *.csv --out DIR``),
the same whichever runner fills it (one process, a local process pool or a Dask cluster):

    DIR/<name>/result.json      one folder per sensor: its fit JSON (``FitResult.to_dict()``,
                                the file ``bayescap fit X.csv --out`` writes) plus a "batch" entry

``<name>`` is the input's file name without its suffix (``roi17.csv`` -> ``roi17``; a second input
of the same name gets ``roi17_2``, then ``_3``; data without a file name ``sensor<i>``). Each
``result.json`` is written atomically (a temporary file in the same folder, fsync'd, then renamed),
by the process that runs the batch, as soon as the chunk of sensors holding it is finished: a crash
loses at most the chunks that were running, never a file half written.

**Resume key.** The "batch" entry is ``{"seed": s, "input_sha256": ..., "config_sha256": ...}``: the
sensor's own seed (:func:`~bayescap.batch.sensor_seeds`, by its position in the batch), a hash of
its data as read (the CSV's numbers and metadata, so an edited CSV or a changed metadata override is
refitted) and a hash of what else sets its numbers (quality preset, fast-path settings, fallback). A
rerun into the same folder skips every sensor whose ``result.json`` carries the same entry and fits
the rest; a sensor that failed has no file and is fitted again.
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import fields
from pathlib import Path

import numpy as np

from bayescap.io.atomic import atomic_write_text

__all__ = ["RESULT_FILE", "batch_entry", "config_digest", "data_digest", "is_done", "sensor_names", "write_result"]

RESULT_FILE = "result.json"

_UNSAFE = re.compile(r"[^A-Za-z0-9._+-]+")
#: the longest folder name taken from a file name (a repeat's "_<k>" and a temporary twin fit in 255 bytes)
MAX_NAME = 200


def sensor_names(sources) -> list[str]:
    """One folder name per input (module docstring): the file name's stem, made safe for a folder
    name, with ``_2``, ``_3``... on repeats; ``sensor<i>`` where there is no file name."""
    used, out = set(), []
    for i, src in enumerate(sources):
        stem = None if src is None or str(src).startswith("<") else Path(str(src)).stem
        stem = _UNSAFE.sub("_", stem).lstrip(".") if stem else ""
        # a folder name has at most 255 bytes: room kept for a "_<k>" suffix (names are ASCII here)
        stem = stem[:MAX_NAME] or f"sensor{i}"
        name, k = stem, 1
        while name in used:
            k += 1
            name = f"{stem}_{k}"
        used.add(name)
        out.append(name)
    return out


def data_digest(data) -> str:
    """SHA-256 of a :class:`~bayescap.io.ptc_csv.PTCData`'s numbers and metadata (not its file name)."""
    h = hashlib.sha256()
    for field in sorted(f.name for f in fields(data)):
        if field in ("source", "row_numbers"):
            continue
        v = getattr(data, field)
        h.update(field.encode())
        if isinstance(v, np.ndarray):
            a = np.ascontiguousarray(v)
            h.update(f"{a.dtype.str}{a.shape}".encode())
            h.update(a.tobytes())
        elif isinstance(v, dict):
            h.update(json.dumps(v, sort_keys=True, default=repr).encode())
        else:
            h.update(repr(v).encode())
    return h.hexdigest()


def config_digest(quality, fallback, settings) -> str:
    """SHA-256 of the settings that change a sensor's numbers besides its data and seed."""
    text = json.dumps({"quality": quality, "fallback": bool(fallback), "settings": repr(settings)}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


def batch_entry(seed, input_sha256, config_sha256) -> dict:
    return {"seed": int(seed), "input_sha256": input_sha256, "config_sha256": config_sha256}


def result_path(out, name) -> Path:
    return Path(out) / name / RESULT_FILE


def is_done(out, name, entry) -> bool:
    """Whether ``DIR/<name>/result.json`` holds this sensor's result (its "batch" entry is ``entry``)."""
    p = result_path(out, name)
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    # a fit JSON, not a stub that only carries the key (it would be reported as a result)
    return (
        isinstance(doc, dict)
        and doc.get("batch") == entry
        and isinstance(doc.get("parameters"), dict)
        and "conversion_gain_e_per_dn" in doc["parameters"]
        and isinstance(doc.get("diagnostics"), dict)
    )


def write_result(out, name, doc, entry) -> Path:
    """Write one sensor's fit JSON with its "batch" entry, atomically; returns the path."""
    p = result_path(out, name)
    doc = dict(doc, batch=entry)
    atomic_write_text(p, json.dumps(doc, indent=2, ensure_ascii=False, allow_nan=False) + "\n")
    return p


def read_result(out, name) -> dict:
    return json.loads(result_path(out, name).read_text(encoding="utf-8"))
