"""Regression checks of a job: expected metric values, tolerances, the comparison.

A job's ``[regression]`` table names expected values per sequence (a JSON file or an inline
table) and tolerances per metric; after a run every sequence's ``metrics.json`` is compared
with them (:func:`compare_regression`), or written as the new expected values.
"""
from __future__ import annotations

import json
from pathlib import Path

from .manifest import now, write_json_atomic
from .schema import is_num, job_error, reject_unknown, resolve, table

__all__ = ["REGRESSION_METRICS", "load_regression", "compare_regression", "regression_table",
           "read_metrics", "write_expected"]

#: Metrics written to every sequence's ``metrics.json`` and compared by a ``[regression]``.
REGRESSION_METRICS = ("keyframe_error", "keyframe_kinks", "half_axes", "gn_frames",
                      "gn_converged", "gn_iterations_total", "gn_grad_norm_max",
                      "gn_energy_final", "flipped_faces", "degenerate_faces")

_REGRESSION_KEYS = {"expected", "tolerances"}
_TOLERANCE_KEYS = {"rtol", "atol", "mode"}
_DEFAULT_TOL = {"rtol": 1e-6, "atol": 1e-12, "mode": "close"}


def load_regression(f: str, base: Path, rt: dict, names: set) -> dict:
    """The ``[regression]`` table of job file ``f``, checked.

    Returns
    -------
    dict
        ``{"expected": {sequence: {metric: value}} or None (the file does not exist yet),
        "expected_path": Path or None, "tolerances": {metric: {"rtol", "atol", "mode"}}}``.

    Raises
    ------
    ShellsplineError
        An unknown key, sequence or metric, an unreadable or invalid expected-values file.
    """
    where = f"{f}: [regression]"
    reject_unknown(where, rt, _REGRESSION_KEYS)
    exp, expected_path = _expected_values(where, base, rt.get("expected"))
    out = {"expected": exp, "expected_path": expected_path,
           "tolerances": _load_tolerances(where, rt)}
    if exp is None:
        return out
    if not isinstance(exp, dict) or not all(isinstance(v, dict) for v in exp.values()):
        raise job_error(f"{where} key 'expected'", "must map sequence names to tables of "
                                                   "metric values")
    for sname, metrics in exp.items():
        if sname not in names:
            raise job_error(f"{where} key 'expected'", f"names an unknown sequence '{sname}'")
        for m in metrics:
            if m not in REGRESSION_METRICS:
                raise job_error(f"{where} key 'expected'",
                                f"sequence '{sname}': unknown metric '{m}' (known: "
                                f"{', '.join(REGRESSION_METRICS)})")
    return out


def _expected_values(where, base, exp):
    """(expected values or None when the file does not exist, the file or None)."""
    if exp is None:
        return {}, None
    if not isinstance(exp, str):
        return exp, None
    expected_path = resolve(base, exp)
    try:
        exp = json.loads(expected_path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return None, expected_path  # run_batch(write_expected=True) creates it
    except OSError as exc:
        raise job_error(f"{where} key 'expected'", f"cannot read '{expected_path}': "
                                                   f"{exc.strerror or exc}") from None
    except ValueError as exc:
        raise job_error(f"{where} key 'expected'", f"'{expected_path}' is not valid JSON: "
                                                   f"{exc}") from None
    if isinstance(exp, dict) and "sequences" in exp:
        exp = exp["sequences"]
    return exp, expected_path


def _load_tolerances(where, rt):
    tols = table(f"{where} key 'tolerances'", rt.get("tolerances", {}))
    out_tols = {}
    for m, t in tols.items():
        w = f"{where} key 'tolerances.{m}'"
        if m not in REGRESSION_METRICS:
            raise job_error(w, f"unknown metric (known: {', '.join(REGRESSION_METRICS)})")
        t = table(w, t)
        reject_unknown(w, t, _TOLERANCE_KEYS)
        rtol, atol, mode = t.get("rtol", 0.0), t.get("atol", 0.0), t.get("mode", "close")
        if not (is_num(rtol) and rtol >= 0 and is_num(atol) and atol >= 0):
            raise job_error(w, f"rtol and atol must be numbers >= 0, got {rtol!r}, {atol!r}")
        if mode not in ("close", "max", "min"):
            raise job_error(w, f"mode must be 'close', 'max' or 'min', got {mode!r}")
        out_tols[m] = {"rtol": float(rtol), "atol": float(atol), "mode": mode}
    return out_tols


def read_metrics(out: Path) -> dict | None:
    """The ``metrics.json`` of an output directory, or None."""
    try:
        return json.loads((out / "metrics.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def write_expected(job, metrics: dict, seqs: list) -> str | None:
    """Write this run's metrics as the job's expected values (every sequence must be done).

    Parameters
    ----------
    job : Job
        With ``regression["expected_path"]`` set; its ``regression["expected"]`` is replaced.
    metrics : dict
        ``{sequence: metrics dict or None}``.
    seqs : list of dict
        The outcomes of the run.

    Returns
    -------
    str or None
        None when written; else why nothing was written (a sequence did not finish), and
        the expected-values file is left as it was.
    """
    bad = [o["name"] for o in seqs if o["status"] not in ("done", "skipped")]
    if bad:
        return (f"expected values not written to {job.regression['expected_path']}: "
                f"sequence{'s' if len(bad) > 1 else ''} {', '.join(bad)} did not finish")
    data = {"job": job.name, "written": now(),
            "sequences": {name: {k: m[k] for k in REGRESSION_METRICS if k in m}
                          for name, m in metrics.items() if m is not None}}
    write_json_atomic(job.regression["expected_path"], data)
    job.regression["expected"] = data["sequences"]
    return None


def compare_regression(regression: dict, metrics: dict) -> dict:
    """Compare measured metrics with the expected values.

    Parameters
    ----------
    regression : dict
        ``Job.regression``.
    metrics : dict
        ``{sequence: metrics dict or None}``.

    Returns
    -------
    dict
        ``{"passed": bool, "checks": [...]}``; a check passes when every element satisfies
        ``|actual - expected| <= atol + rtol |expected|`` (mode ``close``),
        ``actual <= expected + atol + rtol |expected|`` (``max``) or
        ``actual >= expected - atol - rtol |expected|`` (``min``).

    Examples
    --------
    >>> reg = {"expected": {"a": {"gn_frames": 10}},
    ...        "tolerances": {"gn_frames": {"rtol": 0.0, "atol": 1.0, "mode": "max"}}}
    >>> compare_regression(reg, {"a": {"gn_frames": 11}})["passed"]
    True
    >>> compare_regression(reg, {"a": {"gn_frames": 12}})["passed"]
    False
    """
    checks = []
    for sname, exp in regression["expected"].items():
        got = metrics.get(sname)
        for metric, ev in exp.items():
            tol = regression["tolerances"].get(metric, _DEFAULT_TOL)
            c = {"sequence": sname, "metric": metric, "mode": tol["mode"],
                 "rtol": tol["rtol"], "atol": tol["atol"]}
            if got is None or metric not in got:
                c.update(ok=False, deviation=None, note="no result")
            else:
                c.update(_check(ev, got[metric], tol))
            checks.append(c)
    return {"passed": all(c["ok"] for c in checks), "checks": checks}


def _check(ev, av, tol) -> dict:
    """The fields of one check: ``ok``, ``deviation``, ``bound``, ``expected``, ``actual``,
    ``note`` (at the worst element)."""
    import numpy as np

    try:
        e = np.asarray(ev, dtype=np.float64)
        a = np.asarray(av, dtype=np.float64)
    except (TypeError, ValueError):
        return {"ok": False, "deviation": None, "note": "not numeric"}
    if e.shape != a.shape:
        return {"ok": False, "deviation": None,
                "note": f"shape {list(a.shape)} != expected {list(e.shape)}"}
    bound = tol["atol"] + tol["rtol"] * np.abs(e)
    dev = {"close": np.abs(a - e), "max": a - e, "min": e - a}[tol["mode"]]
    nan = ~np.isfinite(a) | ~np.isfinite(e)
    excess = np.where(nan, np.inf, dev - bound)
    worst = int(np.argmax(excess)) if excess.size else 0
    ok = bool(np.all(excess <= 0))
    return {"ok": ok, "deviation": float(dev.ravel()[worst]) if dev.size else 0.0,
            "bound": float(bound.ravel()[worst]) if bound.size else 0.0,
            "expected": float(e.ravel()[worst]) if e.size else None,
            "actual": float(a.ravel()[worst]) if a.size else None,
            "note": "" if ok else (f"element {_index(np.unravel_index(worst, e.shape))}"
                                   if e.ndim else "")}


def _index(idx) -> str:
    """A numpy index tuple as plain ints: ``(3, 0)``, ``(3,)``."""
    return str(tuple(int(i) for i in idx))


def regression_table(regression: dict) -> str:
    """Fixed-width table of the regression checks."""
    rows = [("sequence", "metric", "mode", "expected", "actual", "deviation", "bound", "ok")]
    for c in regression["checks"]:
        def g(k):
            v = c.get(k)
            return "-" if v is None else f"{v:.4g}"
        rows.append((c["sequence"], c["metric"], c["mode"], g("expected"), g("actual"),
                     g("deviation"), g("bound"), ("ok" if c["ok"] else "REGRESSION")
                     + (f" ({c['note']})" if c.get("note") else "")))
    w = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines = ["  ".join(x.ljust(w[i]) if i < 3 else x.rjust(w[i]) if i < 7 else x
                       for i, x in enumerate(r)).rstrip() for r in rows]
    lines.insert(1, "  ".join("-" * x for x in w))
    n_bad = sum(not c["ok"] for c in regression["checks"])
    lines.append(f"regression: {'passed' if regression['passed'] else 'FAILED'} "
                 f"({len(regression['checks']) - n_bad}/{len(regression['checks'])} checks)")
    return "\n".join(lines)
