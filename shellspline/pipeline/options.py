"""The options of :func:`~shellspline.pipeline.interpolate`, validated once.

:class:`InterpolationOptions` canonicalises what does not depend on the mesh (method, boundary
condition, parameters, workers, ...); :func:`interpolation_problem` binds them to the
keyframes (frames and ``K`` through :func:`shellspline.timeline.canonical_frames`, pins,
reference index, coarse vertex count, rigid subset). The stages trust both.
"""
from __future__ import annotations

import inspect
import numbers
import os
from dataclasses import dataclass, field

import numpy as np

from ..errors import ShellsplineError, tol
from ..io.keyframes import Keyframes
from ..metrics import length_scale
from ..mesh.topology import Topology
from ..shells.geodesic import geodesic_interpolation
from ..shells.lta_spline import SPLINES, canonical_spline
from ..shells.nonlinear import nonlinear_spline
from ..shells.prolong import DEFAULT_TRANSFER, TRANSFERS
from ..shells.reconstruct import LARGE_MESH, GaussNewton
from ..timeline import BOUNDARY_CONDITIONS, api_spelling, canonical_bc, canonical_frames

__all__ = ["InterpolationOptions", "InterpolationProblem", "interpolation_problem", "notices",
           "coarse_target", "canonical_choice", "METHODS", "REFERENCES", "RIGID_TRACKS",
           "BOUNDARY_CONDITIONS", "AUTO_COARSE_ABOVE", "AUTO_COARSE_VERTICES",
           "AUTO_NONLINEAR_ABOVE", "FULL_RESOLUTION_WARN", "SPLINES", "DEFAULT_SPLINE",
           "TRANSFERS", "DEFAULT_TRANSFER", "SOLVER_OPTIONS", "coarse_fraction", "size_mismatch",
           "SIZE_RATIO_NOTE"]

METHODS = ("lta", "linear", "geodesic", "nonlinear")
REFERENCES = ("constant", "keyframe", "geodesic")
#: The time spline of the LΘA descriptors when none is asked for (``interpolate``, the CLI's
#: ``--spline``, the batch key ``spline``; the one place that says it): the C² cubic in
#: continuous time, which has no velocity kink at the interior keyframes (the paper's
#: time-discrete spline, ``"discrete"``, has one; on the skinned ground truth of
#: ``benchmarks/bench_real.py`` the continuous spline was closer to the true frames in 19 of 20
#: windows). ``"discrete"`` reproduces the paper (e.g. its Fig. 3,
#: ``pipelines/regression_ellipsoids.toml``). The low-level
#: :func:`~shellspline.shells.lta_spline.lta_spline` keeps the paper's spline as its default.
DEFAULT_SPLINE = "continuous"
#: Where in-between frames are placed rigidly (:func:`shellspline.pipeline.placement_track`).
RIGID_TRACKS = ("fit", "spline", "linear")
#: ``coarse="auto"`` decimates meshes above this many vertices to :data:`AUTO_COARSE_VERTICES`:
#: the library's one "large mesh" size (:data:`shellspline.shells.reconstruct.LARGE_MESH`;
#: timings with and without multiresolution in benchmarks/README.md, ``bench_multires.py``).
AUTO_COARSE_ABOVE = LARGE_MESH
AUTO_COARSE_VERTICES = 1000
#: ``coarse="auto"`` with ``method="nonlinear"`` decimates above this many vertices (to
#: :data:`AUTO_COARSE_VERTICES`): the nonlinear spline takes ~4 min at 1000 vertices (cactus,
#: K = 20) and its cost grows faster than the vertex count. The same for ``method="geodesic"``
#: (one Newton solve on all inner shells of a segment: the 8.4k-vertex horse, 20 frames
#: apart, had not finished its first step after 4.5 min, at 4 GB).
AUTO_NONLINEAR_ABOVE = 2000
#: A full-resolution Gauss–Newton run above this many vertices gets a note on its cost.
FULL_RESOLUTION_WARN = 50_000


def canonical_choice(value, name: str, choices) -> str:
    """``value`` as one of ``choices`` (case and surrounding blanks ignored).

    Raises
    ------
    ShellsplineError
        Naming ``name``, the choices and what was got.
    """
    v = str(value).strip().lower()
    if v not in choices:
        raise ShellsplineError(f"`{name}` must be one of {', '.join(map(repr, choices))}, "
                               f"got {value!r}")
    return v


def _real(value, name: str) -> float:
    """``value`` as a float when it is a real number (not a bool, not a string)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise ShellsplineError(f"`{name}` must be a number, got {value!r}")
    return float(value)


def _whole(value, name: str) -> int:
    """``value`` as an int when it is an integer (an integral float too; not a bool/string)."""
    v = _real(value, name)
    if not np.isfinite(v) or v != int(v):
        raise ShellsplineError(f"`{name}` must be an integer, got {value!r}")
    return int(v)


#: Keywords of :class:`~shellspline.shells.reconstruct.GaussNewton` that ``gn_options`` may set
#: (``T`` and ``pinned`` come from the problem).
GN_OPTIONS = tuple(p for p in inspect.signature(GaussNewton.__init__).parameters
                   if p not in ("self", "T", "pinned"))


def _gn_options(gn_options) -> dict:
    if gn_options is None:
        return {}
    if not isinstance(gn_options, dict):
        raise ShellsplineError(f"`gn_options` must be a dict of GaussNewton options, got "
                               f"{type(gn_options).__name__}")
    bad = [k for k in gn_options if k not in GN_OPTIONS]
    if bad:
        raise ShellsplineError(f"`gn_options`: unknown option {bad[0]!r}; valid: "
                               f"{', '.join(GN_OPTIONS)}")
    return dict(gn_options)


#: Keywords of the solver of each method that ``solver_options`` may set
#: (:func:`~shellspline.shells.geodesic.geodesic_interpolation`,
#: :func:`~shellspline.shells.nonlinear.nonlinear_spline`): not those the pipeline sets itself
#: (the keyframes, frames, weights, pins, boundary condition, start path and progress
#: callbacks, :mod:`shellspline.pipeline.stages`), nor ``energy``, which ``eta``, ``mu`` and
#: ``lam`` make (the report records those). ``"lta"`` takes only the ``max_time_s`` of
#: ``reference="geodesic"`` (:func:`~shellspline.pipeline.interpolation.inapplicable_options`).
SOLVER_OPTIONS = {
    method: tuple(p for p in inspect.signature(solver).parameters
                  if p not in ("Vkey", "frames", "K", "T", "mu", "lam", "eta", "pinned", "bc",
                               "init", "energy", "callback", "progress"))
    for method, solver in (("geodesic", geodesic_interpolation),
                           ("nonlinear", nonlinear_spline))}


def _solver_options(solver_options, method: str) -> dict:
    if solver_options is None:
        return {}
    if not isinstance(solver_options, dict):
        raise ShellsplineError(f"`solver_options` must be a dict, got "
                               f"{type(solver_options).__name__}")
    valid = SOLVER_OPTIONS.get(method)
    bad = [k for k in solver_options if valid is not None and k not in valid]
    if bad:  # other methods: inapplicable_options says what applies
        raise ShellsplineError(f"`solver_options`: unknown option {bad[0]!r} for "
                               f"method={method!r}; valid: {', '.join(valid)}")
    for key, value in solver_options.items():
        _check_solver_value(key, value)
    return dict(solver_options)


#: ``solver_options`` keys whose default is None but whose values are numbers.
_NUMERIC_SOLVER_KEYS = ("max_time_s", "cg_tol")


def _check_solver_value(key: str, value) -> None:
    """A numeric solver option (an int or float default, or :data:`_NUMERIC_SOLVER_KEYS`)
    must be a finite non-negative number (``max_time_s``: positive; an int default: a
    positive integer), so that a bad value is a one-line error here rather than a raw
    ``int()`` or comparison error inside the solver. Other values the solvers check."""
    defaults = [inspect.signature(f).parameters[key].default
                for f in (geodesic_interpolation, nonlinear_spline)
                if key in inspect.signature(f).parameters]
    default = defaults[0] if defaults else None
    integer = isinstance(default, int) and not isinstance(default, bool)
    if not (integer or isinstance(default, float) or key in _NUMERIC_SOLVER_KEYS):
        return
    ok = isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_)) and \
        np.isfinite(value) and value >= 0
    if ok and integer:
        ok = float(value) == int(value) and value >= 1
    if ok and key == "max_time_s":
        ok = value > 0
    if not ok:
        what = ("a positive integer" if integer else "a positive number of seconds"
                if key == "max_time_s" else "a finite non-negative number")
        raise ShellsplineError(f"`solver_options`: {key!r} must be {what}, got {value!r}")


def _canonical_reference(reference):
    if isinstance(reference, (int, np.integer)) and not isinstance(reference, (bool, np.bool_)):
        return int(reference)
    return canonical_choice(reference, "reference", REFERENCES)


@dataclass(frozen=True)
class InterpolationOptions:
    """Canonical, mesh-independent options of an interpolation (see
    :func:`~shellspline.pipeline.interpolate` for their meaning).

    Constructing one validates every field: choices are lower-cased and checked, ``eta``,
    ``mu``, ``lam`` finite and non-negative (``mu`` and ``lam`` not both zero), ``workers``
    >= 1, ``fixpoint`` >= 0, ``reference`` a choice or an int keyframe index, ``spline`` one
    of :data:`SPLINES`, the keys of ``gn_options`` and (for ``"geodesic"`` and
    ``"nonlinear"``) of ``solver_options`` those of the solver (:data:`GN_OPTIONS`,
    :data:`SOLVER_OPTIONS`); ``coarse`` is
    kept as given and resolved against the mesh by :func:`coarse_target`.

    Raises
    ------
    ShellsplineError
        On the first invalid field, naming it.
    """

    method: str = "lta"
    bc: str = "natural"
    eta: float = 1e-3
    mu: float = 1.0
    lam: float = 1.0
    reference: str | int = "constant"
    workers: int = 1
    gn_options: dict = field(default_factory=dict)
    warm_start: bool = True
    solver_options: dict = field(default_factory=dict)
    coarse: object = "auto"
    fine: bool = False
    fixpoint: int = 0
    rigid_track: str = "fit"
    fade_angle: float = 0.5
    spline: str = DEFAULT_SPLINE
    transfer: str = DEFAULT_TRANSFER

    def __post_init__(self):
        put = object.__setattr__.__get__(self)
        put("method", canonical_choice(self.method, "method", METHODS))
        put("rigid_track", canonical_choice(self.rigid_track, "rigid_track", RIGID_TRACKS))
        put("bc", canonical_bc(self.bc))
        for name in ("eta", "mu", "lam"):
            val = _real(getattr(self, name), name)
            if not np.isfinite(val) or val < 0:
                raise ShellsplineError(f"`{name}` must be a finite non-negative number, got "
                                       f"{val!r}")
            put(name, float(val))
        if self.mu == 0 and self.lam == 0:
            raise ShellsplineError("`mu` and `lam` cannot both be zero (the membrane energy "
                                   "would vanish)")
        workers = 1 if self.workers is None else _whole(self.workers, "workers")
        if workers < 1:
            raise ShellsplineError(f"`workers` must be >= 1, got {workers}")
        put("workers", workers)
        if _whole(self.fixpoint, "fixpoint") < 0:
            raise ShellsplineError(f"`fixpoint` must be a non-negative number of iterations, "
                                   f"got {self.fixpoint}")
        put("fixpoint", int(self.fixpoint))
        put("reference", _canonical_reference(self.reference))
        put("gn_options", _gn_options(self.gn_options))
        put("solver_options", _solver_options(self.solver_options, self.method))
        put("warm_start", bool(self.warm_start))
        put("fine", bool(self.fine))
        fade = _real(self.fade_angle, "fade_angle") if self.fade_angle is not None else 0.0
        if not np.isfinite(fade) or fade < 0:
            raise ShellsplineError(f"`fade_angle` must be a finite non-negative angle in "
                                   f"radians, got {self.fade_angle!r}")
        put("fade_angle", fade)
        put("spline", canonical_spline(self.spline))
        put("transfer", canonical_choice(self.transfer, "transfer", TRANSFERS))

    @property
    def periodic(self) -> bool:
        return self.bc == "periodic"


@dataclass
class InterpolationProblem:
    """The keyframes with the options bound to them (what every stage reads).

    Attributes
    ----------
    keyframes : Keyframes
    Vkey : (J,n,3) float64 array
        The keyframe poses the stages work on.
    T : Topology
    frames : (J,) int64 array
    K : int
    pinned : (p,) int64 array or None
    n_coarse : int or None
        Coarse vertex count of a multiresolution run (:func:`coarse_target`).
    rigid_subset : (s,) int64 array or None
        Vertices whose rigid pose places the in-betweens (``None``: all).
    scale : float
        The length ``D`` the keyframes were divided by (:func:`shellspline.metrics.length_scale`): ``Vkey`` is
        ``keyframes.V / D``, and every stage works in these units.
    """

    keyframes: Keyframes
    Vkey: np.ndarray
    T: Topology
    frames: np.ndarray
    K: int
    pinned: np.ndarray | None
    n_coarse: int | None
    rigid_subset: np.ndarray | None = None
    scale: float = 1.0


def _vertex_indices(idx, n: int, name: str):
    """Vertex indices (int array-like, or an ``(n,)`` bool mask, or a str/path read with
    :func:`~shellspline.io.read_indices`) as sorted unique int64 in ``[0, n)``, or ``None``."""
    if idx is None:
        return None
    if isinstance(idx, (str, os.PathLike)):
        from ..io.keyframes import read_indices
        idx = read_indices(idx)
    try:
        arr = np.asarray(idx)
    except Exception as exc:  # ragged nested lists and the like
        raise ShellsplineError(f"`{name}` must be vertex indices or a bool mask: "
                               f"{str(exc).splitlines()[0] if str(exc) else type(exc).__name__}"
                               ) from None
    if arr.dtype == bool:
        if arr.shape != (n,):
            raise ShellsplineError(f"a boolean `{name}` mask must have one entry per vertex "
                                   f"({n}), got shape {arr.shape}")
        arr = np.flatnonzero(arr)
    arr = arr.ravel()
    if arr.size and not np.issubdtype(arr.dtype, np.integer):
        if not np.issubdtype(arr.dtype, np.floating) or not np.isfinite(arr).all() or \
                (arr != np.round(arr)).any():
            raise ShellsplineError(f"`{name}` vertex indices must be integers, got "
                                   f"{arr[:5].tolist()} (dtype {arr.dtype})")
    arr = arr.astype(np.int64)
    if arr.size and (arr.min() < 0 or arr.max() >= n):
        raise ShellsplineError(f"`{name}` indices must lie in [0, {n}), got range "
                               f"[{arr.min()}, {arr.max()}]")
    return np.unique(arr) if arr.size else None


def interpolation_problem(opts: InterpolationOptions, kf: Keyframes, *, frames=None, K=None,
                          pinned=None, rigid_subset=None) -> InterpolationProblem:
    """Bind ``opts`` to the keyframes ``kf``: canonical frames and ``K``, pins (default the
    keyframes' own), the reference keyframe index and the coarse vertex count checked; the
    keyframes divided by their :func:`~shellspline.metrics.length_scale`. ``rigid_subset``:
    vertex indices (at least 3, not on one line in the first keyframe) whose rigid pose
    places the in-betweens (not with ``method="linear"``, which places nothing).

    Raises
    ------
    ShellsplineError
        Naming the argument (``frames``, ``K``, ``pinned``, ``reference``, ``fine``,
        ``rigid_subset``).
    """
    J, n = kf.V.shape[:2]
    pinned = _vertex_indices(kf.pinned if pinned is None else pinned, n, "pinned")
    K_given = K is not None
    frames, K = canonical_frames(J, kf.frames if frames is None else frames, K, opts.bc)
    if opts.bc == "periodic" and not K_given:
        _refuse_repeated_first_pose(kf, frames)
    if isinstance(opts.reference, int) and not 0 <= opts.reference < J:
        raise ShellsplineError(f"`reference` keyframe index must lie in [0, {J}), got "
                               f"{opts.reference}")
    n_coarse = None
    if opts.method == "geodesic" and opts.fine:
        raise ShellsplineError("`fine=True` refines the LΘA reconstruction at full resolution; "
                               "method='geodesic' has none (with `coarse` its coarse "
                               "geodesics are prolonged by detail transfer)")
    if opts.method in ("lta", "nonlinear", "geodesic"):
        n_coarse = coarse_target(opts.coarse, n, opts.method)
        if opts.fine and n_coarse is None:
            raise ShellsplineError("`fine=True` refines a multiresolution run: it needs `coarse` "
                                   f"(a vertex count or fraction below the {n} vertices), got "
                                   f"coarse={opts.coarse!r}")
    subset = _rigid_subset(rigid_subset, kf.V[0], opts.method)
    D = length_scale(kf.V[0], kf.topology.F)
    return InterpolationProblem(keyframes=kf, Vkey=kf.V / D if D != 1.0 else kf.V,
                                T=kf.topology, frames=frames, K=K, pinned=pinned,
                                n_coarse=n_coarse, rigid_subset=subset, scale=D)


def _refuse_repeated_first_pose(kf: Keyframes, frames) -> None:
    """Refuse a periodic loop whose last keyframe repeats the first (the usual way to close a
    loop in a DCC tool): frame ``K`` is frame 0 again one keyframe gap after it, so the loop
    would reach that pose twice and wander off it in between (on the horse, by 0.1 of its
    1.4 bounding-box diagonal) instead of closing at the repeated keyframe."""
    V0, Vl = kf.V[0], kf.V[-1]
    # the same pose to float32 rounding (a re-export of the same frame)
    if len(kf.V) < 2 or np.abs(Vl - V0).max() > 1e-6 * max(np.abs(V0).max(), tol.zero):
        return
    names = list(getattr(kf, "names", None) or [])
    name = f" ({names[-1]!r})" if len(names) == len(kf.V) else ""
    f = int(frames[-1])
    raise ShellsplineError(
        f"the last keyframe{name}, at frame {f}, repeats the first: with bc='periodic' frame "
        f"K is frame 0 again (here K={f + int(frames[-1] - frames[-2])}), so the loop would "
        f"return to that pose twice; drop the repeated keyframe and close the loop at its "
        f"frame with K={f}")


def _rigid_subset(subset, V0, method):
    subset = _vertex_indices(subset, V0.shape[0], "rigid_subset")
    if subset is None:
        return None
    if method == "linear":
        raise ShellsplineError("`rigid_subset` places the in-betweens of a shell method (lta, "
                               "geodesic, nonlinear); method='linear' places nothing")
    subset = np.unique(subset)
    X = V0[subset] - V0[subset].mean(axis=0)
    sv = np.linalg.svd(X, compute_uv=False) if len(subset) >= 3 else np.zeros(2)
    if len(subset) < 3 or sv[1] <= 1e-9 * max(sv[0], tol.zero):
        raise ShellsplineError(f"`rigid_subset` must hold at least 3 vertices not on one line "
                               f"(a rigid pose needs them), got {len(subset)} vertices"
                               + (" on a line" if len(subset) >= 3 else ""))
    return subset


def notices(opts: InterpolationOptions, prob: InterpolationProblem) -> list[str]:
    """The one-line notes a run starts with (extrapolated frames, moving pins, where the
    nonlinear spline runs, the cost of a large full-resolution run)."""
    out = []
    frames, K, n, Vkey = prob.frames, prob.K, prob.Vkey.shape[1], prob.keyframes.V
    size = size_mismatch(prob.keyframes)
    if size:
        out.append(size)
    if opts.bc != "periodic" and K > frames[-1] and opts.method != "linear":
        out.append(f"frames {int(frames[-1]) + 1}..{K} lie after the last keyframe: the "
                   "spline extrapolates them (linearly in its variables)")
    if prob.pinned is not None:
        spread = np.abs(Vkey[:, prob.pinned] - Vkey[0, prob.pinned]).max()
        if spread > 0:
            out.append(f"pinned vertices move between keyframes (max {spread:.3g}); "
                       "each frame pins them at their blended position")
    n_coarse = prob.n_coarse
    # the Discrete Shells methods (fine=True is refused for geodesic, and refines nonlinear)
    heavy = {"geodesic": ("piecewise geodesics", f"one Newton solve with 3 x {n} x (frames per "
                          "gap - 1) unknowns per keyframe gap, minutes per step"),
             "nonlinear": ("nonlinear spline", "expect far more than the ~4 min it takes at "
                           f"{AUTO_COARSE_VERTICES}")}
    if opts.method in heavy and not opts.fine:
        what, cost = heavy[opts.method]
        if n_coarse is not None and coarse_target(opts.coarse, n) is None:
            out.append(f"{opts.method}: solving on {n_coarse} coarse vertices and prolonging "
                       f"to {n} (--coarse none: all {n}, far slower)")
        elif n_coarse is None and n > AUTO_NONLINEAR_ABOVE:
            out.append(f"{what} on all {n} vertices: {cost} (--coarse "
                       f"{AUTO_COARSE_VERTICES} solves there and prolongs)")
    if opts.method not in ("lta", "nonlinear"):
        return out
    if (n_coarse is None or opts.fine) and n > FULL_RESOLUTION_WARN:
        out.append(f"Gauss–Newton at full resolution on {n} vertices takes minutes and "
                   "gigabytes (measured: 154k vertices, K = 50, --fine from 1000 coarse "
                   "vertices, 2 workers: 7.1 min, 6.8 GiB)" +
                   ("" if opts.fine else "; here frames start from the keyframe blend, "
                    "not from a prolonged coarse result; the multiresolution path "
                    f"(--coarse, default above {AUTO_COARSE_ABOVE} vertices) takes seconds"))
    return out


#: :func:`size_mismatch` notes a keyframe whose size (square root of its surface area) is at
#: least this many times the first keyframe's, or at most its inverse: a pose does not grow
#: that much (the ellipsoids of ``data_synth`` change by 0.77, the horse and cactus poses by
#: under 1.1), files exported in different units (cm and m: 100) do.
SIZE_RATIO_NOTE = 2.0


def size_mismatch(kf: Keyframes) -> str:
    """A note on the keyframe whose size is furthest from the first keyframe's, when it is
    :data:`SIZE_RATIO_NOTE` times larger or smaller (``""`` otherwise).

    Every method is unit-free (the keyframes are divided by the first one's
    :func:`~shellspline.metrics.length_scale`), but a keyframe exported in another unit is
    another shape to them: the in-betweens grow and shrink through it.

    Examples
    --------
    >>> import trimesh
    >>> from shellspline.io import keyframes_from_arrays
    >>> m = trimesh.creation.icosphere(subdivisions=1)
    >>> note = size_mismatch(keyframes_from_arrays([m.vertices, 100 * m.vertices], m.faces))
    >>> note.split(",")[0]
    'keyframe 1 is 100 times the size of keyframe 0'
    >>> size_mismatch(keyframes_from_arrays([m.vertices, 1.5 * m.vertices], m.faces))
    ''
    """
    D = np.array([length_scale(V, kf.topology.F) for V in kf.V])
    ratio = D / D[0]
    j = int(np.argmax(np.maximum(ratio, 1.0 / ratio)))
    r = float(ratio[j])
    if 1.0 / SIZE_RATIO_NOTE < r < SIZE_RATIO_NOTE:
        return ""
    names = list(getattr(kf, "names", None) or [])

    def called(i):  # the file as given, else the keyframe's index
        name = names[i] if len(names) == len(kf.V) else f"keyframe {i}"
        return name if name == f"keyframe {i}" else f"{name!r} (keyframe {i})"

    what = f"{r:.3g} times" if r > 1 else f"1/{1 / r:.3g} of"
    return (f"{called(j)} is {what} the size of {called(0)}, measured as the square root of "
            "the surface area: the in-betweens grow and shrink with it; if the files use "
            "different units (e.g. cm and m), scale them to one")


def coarse_target(coarse, n: int, method: str = "lta", *, spell=None):
    """Canonical coarse vertex count of a mesh with ``n`` vertices, or None for a
    single-resolution run.

    Parameters
    ----------
    coarse : "auto", "none", int, float in (0, 1), or such a string
        ``"auto"``: :data:`AUTO_COARSE_VERTICES` above :data:`AUTO_COARSE_ABOVE` vertices
        (above :data:`AUTO_NONLINEAR_ABOVE` with ``method="nonlinear"`` or ``"geodesic"``).
    n : int
    method : str
    spell : callable(option, value=...) -> str, optional
        How the message of an invalid ``coarse`` names it (the CLI's ``--coarse``); default
        :func:`~shellspline.timeline.api_spelling`.

    Raises
    ------
    ShellsplineError
        For a ``coarse`` that is none of these.

    Examples
    --------
    >>> coarse_target(0.1, 5000), coarse_target("700", 5000), coarse_target(6000, 5000)
    (500, 700, None)
    """
    if coarse is None or (isinstance(coarse, str) and coarse.strip().lower() == "auto"):
        above = AUTO_NONLINEAR_ABOVE if method in ("nonlinear", "geodesic") \
            else AUTO_COARSE_ABOVE
        return AUTO_COARSE_VERTICES if n > above else None
    spell = spell or api_spelling
    given = coarse
    coarse = _coarse_number(coarse, spell)
    if coarse is None:
        return None
    if isinstance(coarse, bool):
        raise ShellsplineError(_bad_coarse(given, spell))
    if isinstance(coarse, (float, np.floating)) and 0 < coarse < 1:
        target = int(round(coarse * n))
    elif np.isfinite(float(coarse)) and float(coarse) == int(coarse) and int(coarse) >= 4:
        target = int(coarse)
    else:
        raise ShellsplineError(_bad_coarse(given, spell))
    return None if target >= n else max(target, 4)


def _bad_coarse(coarse, spell) -> str:
    """The message for a ``coarse`` that is none of the values :func:`coarse_target` takes."""
    return (f"{spell('coarse')} must be 'auto', 'none', a vertex count >= 4 or a fraction in "
            f"(0, 1), got {coarse!r}")


def _coarse_number(coarse, spell=api_spelling):
    """A ``coarse`` other than ``"auto"`` as given, a string read as its number (``"0.1"``,
    ``"700"``, ``"1e3"``: a float where it has a point or an exponent), or None for
    ``"none"``."""
    if not isinstance(coarse, str):
        return coarse
    c = coarse.strip().lower()
    if c in ("none", "off", "no"):
        return None
    try:
        return float(c) if any(ch in c for ch in ".e") else int(c)
    except ValueError:
        raise ShellsplineError(_bad_coarse(coarse, spell)) from None


def coarse_fraction(coarse):
    """The fraction of the vertices that ``coarse`` asks for, or None.

    Parameters
    ----------
    coarse : "auto", "none", int, float in (0, 1), or such a string
        As :func:`coarse_target` takes it.

    Returns
    -------
    float or None
        ``coarse`` as a float when it is a fraction in (0, 1) (or a string of one); None for
        ``"auto"``, ``"none"`` and a vertex count. :func:`coarse_target` rounds it times the
        vertex count.

    Raises
    ------
    ShellsplineError
        For a string that is none of these.

    Examples
    --------
    >>> coarse_fraction(0.25), coarse_fraction("0.999"), coarse_fraction(700)
    (0.25, 0.999, None)
    """
    if coarse is None or (isinstance(coarse, str) and coarse.strip().lower() == "auto"):
        return None
    c = _coarse_number(coarse)
    return float(c) if isinstance(c, (float, np.floating)) and 0 < c < 1 else None
